"""What an identification must pass before its model is reported as good, stored or made active.

Three checks, shared by every path (a measurement file, a collection, a bag, a MUKCa folder,
the live suite):

1. **The data are plausible for the arm** (:func:`data_problems`, before any fit): joint values
   inside the model's limits (radians read as degrees and the reverse named), the measured
   positions spread like the arm's tip does at those joints (metres read as millimetres and the
   reverse named), known sphere distances no longer than the arm can span, enough equations.
2. **The solve stays where a real arm can be** (:class:`DeviationBounds`): every identified
   deviation from nominal within a few millimetres and tens of milliradians (the defaults,
   which a user can see and change). The solver is bounded by them, so it cannot collapse the
   arm onto a degenerate solution (a ball that never moves fits every plane); a parameter that
   ends on its bound is not determined by the data, and the result is refused.
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
MAX_DEVIATION_M = 0.005          # a real arm's joint origins are off by < ~1 mm; 5 mm is ample
MAX_DEVIATION_RAD = 0.05         # and its axes by < ~5 mrad, its zero offsets by < ~20 mrad
AT_BOUND = 0.99                  # a deviation beyond this fraction of its bound sits on it
LIMIT_SLACK_RAD = 0.05           # joint readings may pass a URDF limit by a little
SMALLEST_JOINT_SPAN_RAD = 0.2    # all joints within 11.5 deg: no arm is calibrated so
                                 # (2 pi rad read as degrees is 0.11 rad)
SCALE_BAND = 5.0                 # measured spread / the tip's spread within [1/5, 5]
EQUATIONS_PER_UNKNOWN = 2.0      # fewer equations than twice the unknowns: refused
_ANGLE_FIELDS = ('roll', 'pitch', 'yaw', 'alpha', 'theta', 'compliance')  # (compliance.py)


@dataclass(frozen=True)
class DeviationBounds:
    """How far from nominal an identified parameter may be: ``length_m`` [m] for lengths (and
    a prismatic joint's zero offset), ``angle_rad`` [rad] for angles and zero offsets."""

    length_m: float = MAX_DEVIATION_M
    angle_rad: float = MAX_DEVIATION_RAD

    def __post_init__(self) -> None:
        if not (self.length_m > 0.0 and self.angle_rad > 0.0
                and math.isfinite(self.length_m) and math.isfinite(self.angle_rad)):
            raise ValueError(f'deviation bounds must be finite and > 0, got '
                             f'{self.length_m} m and {self.angle_rad} rad')

    def half_widths(self, model: KinematicModel, names: tuple[str, ...]) -> Array:
        """The bound of each named parameter [m or rad]."""
        return np.array([self.angle_rad if is_angle(model, n) else self.length_m
                         for n in names], dtype=float)

    def describe(self) -> str:
        return f'{self.length_m * 1e3:g} mm / {self.angle_rad * 1e3:g} mrad'


def is_angle(model: KinematicModel, name: str) -> bool:
    """Whether parameter ``name`` (a model field or ``offset_<joint>``) is an angle."""
    if name.startswith('offset_'):
        joint = model.joint_names.index(name[len('offset_'):])
        return not (len(model.prismatic) and bool(model.prismatic[joint]))
    return name.split('_', 1)[0] in _ANGLE_FIELDS


def at_bounds(model: KinematicModel, names: tuple[str, ...], deltas: ArrayLike,
              bounds: DeviationBounds) -> list[str]:
    """One problem per parameter whose deviation sits on its bound."""
    deltas = np.asarray(deltas, dtype=float)
    widths = bounds.half_widths(model, names)
    out = []
    for name, d, w in zip(names, deltas, widths):
        if not abs(d) < AT_BOUND * w:
            unit, scale = ('mrad', 1e3) if is_angle(model, name) else ('mm', 1e3)
            out.append(f'{name} ran to its bound ({d * scale:+.3f} {unit} off nominal, '
                       f'bound {w * scale:g} {unit}): the data do not determine it (too few or too '
                       'alike poses, or a measurement that cannot see it: try --model '
                       'offsets), or the arm is off by more than a real arm is (check the '
                       'units; the bound is --max-deviation-mm / --max-deviation-mrad)')
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
