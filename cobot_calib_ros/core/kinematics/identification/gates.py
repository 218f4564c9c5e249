"""What an identification must pass before its model is reported as good, stored or made active.

Three checks, shared by every path (a measurement file, a collection, a bag, a MUKCa folder,
the live suite):

1. **The data are plausible for the arm** (:func:`data_problems`, before any fit): joint values
   inside the model's limits (radians read as degrees and the reverse named), the measured
   positions spread like the arm's tip does at those joints (metres read as millimetres and the
   reverse named), known sphere distances no longer than the arm can span, enough equations.
2. **Each parameter is judged by what the data say about it**: the solve is maximum a
   posteriori with a Gaussian prior around nominal of how far a real arm deviates
   (:func:`typical_deviation`: 1 mm, 10 mrad), and each parameter's standard deviation from
   that fit (s^2 (J^T W J)^-1 at the solution, W the robust loss's weights, the prior's rows
   included) is set against it. One the data do not determine (std above 0.9 of the prior's
   sigma: :func:`determined`) is held at nominal with its reason
   (:func:`undetermined_reason`) and never sinks the calibration; one far from nominal but
   determined is kept and reported as large (:func:`large_note`: a zero offset of degrees is
   typical of encoder zeroing). The solve stays where a real arm can be
   (:class:`DeviationBounds`: a few millimetres, tens of milliradians, a zero offset 20
   degrees; the defaults, which a user can see and change), so it cannot collapse the arm onto
   a degenerate solution (a ball that never moves fits every plane); a determined parameter
   that ends on its bound is a wrong model, and the result is refused.
3. **The result is better than what it replaces** (:func:`judge`): converged, held-out error no
   worse than the nominal model's, and not below the measurement's own noise (a fit that
   predicts held-out data better than the instrument measures them has found a degenerate
   model, not the arm).

A :class:`Verdict` carries the problems; it passes when there are none. Its :meth:`line` is the
one line a command prints: ``REFUSED: <reason>; <reason>``.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.kinematics.model import KinematicModel

Array = NDArray[np.float64]
MAX_DEVIATION_M = 0.02           # a real arm's joint origins are off by < ~1 mm, a humanoid's
                                 # by several: 20 mm is no drawing error but a wrong model
MAX_DEVIATION_RAD = 0.05         # and its axes by < ~5 mrad
MAX_OFFSET_RAD = 0.35            # its zero offsets: humanoid and mobile arms by degrees (encoder
                                 # zeroing); 20 deg is no zeroing error but a wrong model
AT_BOUND = 0.99                  # a deviation beyond this fraction of its bound sits on it
# How far a real arm of any kind deviates from its drawing (one sigma): the Gaussian prior
# around nominal of the solve (measurement_fit.judged_fit) and the yardstick a parameter's
# standard deviation is judged by: 1 mm for lengths, 10 mrad for angles and zero offsets; a
# compliance, rad/(N m), has no nominal and no prior, its yardstick 1e-3 (a light arm's joint
# stiffness is ~1000 N m/rad)
TYPICAL_LENGTH_M = 1e-3
TYPICAL_ANGLE_RAD = 10e-3
TYPICAL_COMPLIANCE = 1e-3
DETERMINED = 0.9                 # determined: std from the fit with the prior <= 0.9 of the
                                 # prior's sigma (the data add >= 1/4 of the prior's information)
LARGE = 3.0                      # large: a determined deviation beyond 3 typical ones
LIMIT_SLACK_RAD = 0.05           # joint readings may pass a URDF limit by a little
SMALLEST_JOINT_SPAN_RAD = 0.2    # all joints within 11.5 deg: no arm is calibrated so
                                 # (2 pi rad read as degrees is 0.11 rad)
SCALE_BAND = 5.0                 # measured spread / the tip's spread within [1/5, 5]
EQUATIONS_PER_UNKNOWN = 2.0      # fewer equations than twice the unknowns: refused
_ANGLE_FIELDS = ('roll', 'pitch', 'yaw', 'alpha', 'theta', 'compliance')  # (compliance.py)


@dataclass(frozen=True)
class DeviationBounds:
    """How far from nominal an identified parameter may be: ``length_m`` [m] for lengths (and
    a prismatic joint's zero offset), ``angle_rad`` [rad] for angles, ``offset_rad`` [rad]
    for a revolute joint's zero offset."""

    length_m: float = MAX_DEVIATION_M
    angle_rad: float = MAX_DEVIATION_RAD
    offset_rad: float = MAX_OFFSET_RAD      # a revolute joint's zero offset (is_zero_offset)

    def __post_init__(self) -> None:
        values = (self.length_m, self.angle_rad, self.offset_rad)
        if not all(v > 0.0 and math.isfinite(v) for v in values):
            raise ValueError(f'deviation bounds must be finite and > 0, got '
                             f'{self.length_m} m, {self.angle_rad} rad and {self.offset_rad} rad')

    def half_widths(self, model: KinematicModel, names: tuple[str, ...]) -> Array:
        """The bound of each named parameter [m or rad]."""
        return np.array([self.offset_rad if is_zero_offset(model, n) else
                         self.angle_rad if is_angle(model, n) else self.length_m
                         for n in names], dtype=float)

    def describe(self) -> str:
        return (f'{self.length_m * 1e3:g} mm / {self.angle_rad * 1e3:g} mrad (zero offsets '
                f'{self.offset_rad * 1e3:g} mrad)')


def is_angle(model: KinematicModel, name: str) -> bool:
    """Whether parameter ``name`` (a model field or ``offset_<joint>``) is an angle."""
    if name.startswith('offset_'):
        joint = model.joint_names.index(name[len('offset_'):])
        return not (len(model.prismatic) and bool(model.prismatic[joint]))
    return name.split('_', 1)[0] in _ANGLE_FIELDS


def is_zero_offset(model: KinematicModel | None, name: str) -> bool:
    """Whether ``name`` turns a revolute joint about its own axis (its zero offset: where an
    encoder zeroing error shows): ``offset_<joint>``, an MDH ``theta_<i>``, or a URDF origin's
    ``yaw_<joint>`` when the origin's roll and pitch are nominally 0 (the placement is
    Rz(yaw) Ry(pitch) Rx(roll) before the joint's own Rz)."""
    if model is None or not is_angle(model, name) or name.startswith('compliance'):
        return False
    field, _, rest = name.partition('_')
    if field == 'offset':
        return True
    if field == 'theta' and model.kind == 'mdh':
        return True
    if field == 'yaw' and model.kind == 'origin' and rest in model.joint_names:
        joint = model.joint_names.index(rest)
        if len(model.prismatic) and model.prismatic[joint]:
            return False
        row = model.rows()[joint]
        return abs(math.remainder(row[3], 2 * math.pi)) < 1e-9 and \
            abs(math.remainder(row[4], 2 * math.pi)) < 1e-9
    return False


def typical_deviation(model: KinematicModel | None, name: str) -> float:
    """How far a real arm's parameter ``name`` deviates from its drawing (one sigma) [m, rad
    or rad/(N m)]: the yardstick its standard deviation is judged by."""
    if name.startswith('compliance'):
        return TYPICAL_COMPLIANCE
    return TYPICAL_ANGLE_RAD if is_angle(model, name) else TYPICAL_LENGTH_M


def _unit(model: KinematicModel | None, name: str) -> tuple[str, float]:
    if name.startswith('compliance'):
        return 'mrad/(N m)', 1e3
    return ('mrad', 1e3) if is_angle(model, name) else ('mm', 1e3)


def determined(model: KinematicModel | None, name: str, std: float) -> bool:
    """Whether the data determine ``name``: its standard deviation [m or rad] from the fit
    within :data:`DETERMINED` of a real arm's typical deviation (a NaN or inf std: not)."""
    return bool(std <= DETERMINED * typical_deviation(model, name))


def undetermined_reason(model: KinematicModel | None, name: str, std: float) -> str:
    """Why ``name`` is held at nominal: its std against what a real arm deviates by."""
    unit, scale = _unit(model, name)
    typical = typical_deviation(model, name) * scale
    spread = 'no bound' if not math.isfinite(std) else f'+- {std * scale:.3g} {unit}'
    return (f'the data do not determine it ({spread} from the fit, where a '
            f'real arm deviates by ~{typical:g} {unit}; more or more varied poses, or a '
            'measurement that sees it, would)')


def large_note(model: KinematicModel | None, name: str, delta: float,
               std: float) -> str | None:
    """'<name> +61.0 mrad +- 0.4: large, ...' for a determined deviation beyond :data:`LARGE`
    typical ones; None when it is not large."""
    if not abs(delta) > LARGE * typical_deviation(model, name):
        return None
    unit, scale = _unit(model, name)
    why = ('typical of encoder zeroing' if is_zero_offset(model, name) else
           'a soft joint, or link bending lumped into it' if name.startswith('compliance') else
           'check the drawing or the assembly' if not is_angle(model, name) else
           'check the mounting of this joint\'s axis')
    return f'{name} {delta * scale:+.4g} {unit} +- {std * scale:.2g}: large, {why}'


def at_bounds(model: KinematicModel, names: tuple[str, ...], deltas: ArrayLike,
              bounds: DeviationBounds) -> list[str]:
    """One problem per parameter whose deviation sits on its bound. Called on determined
    parameters (an undetermined one is held at nominal before): the data put the arm where
    no real arm is, which is a wrong model, not an arm off its drawing."""
    deltas = np.asarray(deltas, dtype=float)
    widths = bounds.half_widths(model, names)
    out = []
    for name, d, w in zip(names, deltas, widths):
        if not abs(d) < AT_BOUND * w:
            unit, scale = _unit(model, name)
            out.append(f'{name} ran to its bound ({d * scale:+.3f} {unit} off nominal, '
                       f'bound {w * scale:g} {unit}), where the data pull it further: the '
                       'model does not fit these data (a measurement that cannot see the '
                       'full model, e.g. plane touches: try --model offsets; or a unit '
                       'mistake), or the arm is off by more than a real arm is (the bound is '
                       '--max-deviation-mm / --max-deviation-mrad)')
    return out


@dataclass(frozen=True)
class Verdict:
    """The gate's verdict on one identification: its problems (none: passed)."""

    problems: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        return not self.problems

    def line(self) -> str:
        return 'passed' if self.passed else 'REFUSED: ' + '; '.join(self.problems)

    def to_dict(self) -> dict:
        return {'passed': self.passed, 'problems': list(self.problems)}


def refuse(problems: list[str], code: ErrorCode = ErrorCode.IMPLAUSIBLE_FIT) -> None:
    """Raise the problems as one Refusal line (nothing fitted, nothing stored)."""
    if problems:
        raise Refusal(Failure(code, Verdict(tuple(problems)).line()))


def joint_problems(model: KinematicModel, q: ArrayLike) -> list[str]:
    """Joint values against the model's limits; the likely unit mistake named."""
    q = np.asarray(q, dtype=float)
    lower = np.asarray(model.lower, dtype=float) - LIMIT_SLACK_RAD
    upper = np.asarray(model.upper, dtype=float) + LIMIT_SLACK_RAD
    revolute = ~np.asarray(model.prismatic, dtype=bool) if len(model.prismatic) else \
        np.ones(q.shape[1], bool)
    outside = (q < lower) | (q > upper)
    if outside.any():
        row, joint = (int(v) for v in np.argwhere(outside)[0])
        name = model.joint_names[joint]
        in_degrees = np.all((np.radians(q[:, revolute]) >= lower[revolute])
                            & (np.radians(q[:, revolute]) <= upper[revolute]))
        hint = ('they look like degrees: declare units.angle: deg' if in_degrees and
                revolute[joint] else 'check the joint columns and units.angle')
        return [f'joint {name} reads {q[row, joint]:.4g} at row {row}, outside its limits '
                f'[{model.lower[joint]:.4g}, {model.upper[joint]:.4g}] '
                f'({int(outside.sum())} values outside): {hint}']
    span = float(np.ptp(q[:, revolute], axis=0).max()) if revolute.any() and len(q) else 0.0
    if len(q) > 1 and span < SMALLEST_JOINT_SPAN_RAD:
        return [f'the revolute joints move by at most {span:.4g} rad ({math.degrees(span):.3g} '
                'deg) over the data: no calibration moves so little; they look like radians '
                'declared as degrees: declare units.angle: rad']
    return []


def _spread(p: Array) -> float:
    """RMS distance of points (m, 3) from their centroid."""
    return float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))


def reach(model: KinematicModel) -> float:
    """An upper bound of the distance from the base to the tip [m]: the joint origins'
    lengths added up (a prismatic joint's stroke included)."""
    from cobot_calib_ros.core.kinematics.model import placement
    total = sum(float(np.linalg.norm(placement(model.kind, r)[:3, 3])) for r in model.rows())
    total += float(np.linalg.norm(np.asarray(model.flange)[:3, 3]))
    if len(model.prismatic):
        slides = np.asarray(model.prismatic, dtype=bool)
        total += float(np.sum(np.maximum(np.abs(model.lower[slides]),
                                         np.abs(model.upper[slides]))))
    return total


def offset_problems(model: KinematicModel, offset: ArrayLike, what: str) -> list[str]:
    """A ball or marker offset on the tip [m] no longer than the arm's reach."""
    length, limit = float(np.linalg.norm(offset)), reach(model)
    if length <= limit:
        return []
    ratio = length / limit
    hint = ('it looks like millimetres declared as metres: declare units.length: mm'
            if ratio > 20.0 else 'check it and units.length')
    return [f'the {what} is {length * 1e3:.4g} mm from the tip, longer than the arm\'s reach '
            f'({limit * 1e3:.4g} mm): {hint}']


def scale_problems(measured: ArrayLike, modelled: ArrayLike, what: str) -> list[str]:
    """The spread of ``measured`` positions [m] against the arm's ``modelled`` ones at the same
    joints [m]: a unit mistake shows as a factor of about 1000."""
    s_meas, s_model = _spread(np.asarray(measured)), _spread(np.asarray(modelled))
    if s_model <= 0.0 or len(measured) < 3:
        return []
    ratio = s_meas / s_model
    if 1.0 / SCALE_BAND <= ratio <= SCALE_BAND:
        return []
    if ratio < 1.0 / SCALE_BAND:
        hint = ('they look like metres declared as millimetres: declare units.length: m'
                if 1e-4 < ratio < 1e-2 else 'check the position columns and units.length')
    else:
        hint = ('they look like millimetres declared as metres: declare units.length: mm'
                if 1e2 < ratio < 1e4 else 'check the position columns and units.length')
    return [f'the {what} spread {s_meas * 1e3:.4g} mm where the arm\'s tip spreads '
            f'{s_model * 1e3:.4g} mm at the same joint values (x {ratio:.3g}): {hint}']


def distance_problems(distances, centres) -> list[str]:
    """Known sphere-centre distances [m] against the distances of the centres the nominal arm
    puts them at (``centres[i]``, (3,) [m])."""
    for i, j, d in distances:
        nominal = float(np.linalg.norm(np.asarray(centres[i]) - np.asarray(centres[j])))
        if nominal <= 0.0:
            continue
        ratio = d / nominal
        if 1.0 / SCALE_BAND <= ratio <= SCALE_BAND:
            continue
        hint = ('it looks like millimetres declared as metres: declare units.length: mm'
                if 1e2 < ratio < 1e4 else
                'it looks like metres declared as millimetres: declare units.length: m'
                if 1e-4 < ratio < 1e-2 else 'check the distances')
        return [f'the known distance of spheres {i} and {j} is {d * 1e3:.4g} mm where the '
                f'arm puts them {nominal * 1e3:.4g} mm apart: {hint}']
    return []


def equation_problems(equations: int, unknowns: int, rows: int) -> list[str]:
    """Enough equations for the unknowns, with room to spare for the noise."""
    need = EQUATIONS_PER_UNKNOWN * unknowns
    if equations >= need:
        return []
    return [f'{rows} rows give {equations} equations for {unknowns} unknowns; at least '
            f'{int(math.ceil(need))} equations are needed ({EQUATIONS_PER_UNKNOWN:g} per '
            'unknown): measure more rows or use a smaller --model']


def result_problems(converged: bool, held_out_nominal_m: float, held_out_calibrated_m: float,
                    noise_m: float = 0.0, what: str = 'held-out position RMSE') -> list[str]:
    """A fit that did not converge, is worse than nominal held out, or is better than the
    measurement's noise allows."""
    out = []
    if not converged:
        out.append('the solver did not converge: the model may be far from the optimum')
    cal, nom = held_out_calibrated_m, held_out_nominal_m
    if not (math.isfinite(cal) and math.isfinite(nom)):
        out.append(f'the {what} is not finite ({nom} -> {cal} m)')
    elif cal > nom:
        out.append(f'the calibrated model is worse than nominal: {what} {nom * 1e3:.4f} -> '
                   f'{cal * 1e3:.4f} mm (over-fitted: too few or too alike rows for the '
                   'parameters; measure more or use --model offsets)')
    if noise_m > 0.0 and math.isfinite(cal) and cal < 0.5 * noise_m:
        out.append(f'the {what} {cal * 1e3:.4f} mm is below the measurement\'s own noise '
                   f'({noise_m * 1e3:.4f} mm): the model is degenerate (it explains the noise '
                   'too), not the arm')
    return out
