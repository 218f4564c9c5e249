"""One kinematic calibration of live data, start to end: the identification, validation, outcome.

The live path of the one identification engine, used by the ``kinematic_identifier`` node
(and through it by ``cobot-calib identify --attach`` / ``--source COLLECTION``, bags) and the
demo:

1. the observations become :class:`Measurements` (sphere couplings: kind ``spheres``, the
   coupling's nominal centre as the ball; a laser tracker: kind ``points``, the reflector as
   the marker), the model's own error model (``mdh`` for a DH table, ``full`` for a URDF);
2. :func:`measurement_fit.calibrate`, the call a measurement file ends in too: the gates' data
   checks (a Refusal), identifiability on the data's Jacobian (the base motion relative data
   cannot see, and the tool centre, come first, so the first joint's row and every parameter
   equivalent to moving the base go, and the tool centre is always kept: where an arm
   parameter and the tool are redundant, the last joint's d against the ball's z, the
   difference is the coupling's mounting, and the arm stays nominal there, so another tool on
   the same flange, the probe, does not inherit the coupling's offset), the bounded solve with
   the chosen solver and loss (progress and cancel through ``callback``), the gates' problems
   with the fit (a parameter on its bound, not converged);
3. validation: absolute errors against laser-tracker sets, nominal against calibrated, as the
   paper's Table 5; each model registered to the tracker by its own best rigid fit (a relative
   calibration has no world frame); a calibrated mean error above the nominal one is a gate
   problem too. A result whose verdict did not pass is reported with it and never stored or
   made active;
4. the outcome, which the store turns into a record (store.records.KinematicRecord) and writes
   as JSON, YAML and a calibrated URDF.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.kinematics.identification import gates
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds, Verdict
from cobot_calib_ros.core.kinematics.identification.measurements import Measurements
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import tool_frames, TOOL_NAMES
from cobot_calib_ros.core.kinematics.identification.validation import (
    absolute_errors, error_stats, table6)
from cobot_calib_ros.core.kinematics.model import KinematicModel
from cobot_calib_ros.core.kinematics.plans import even_subset

Array = NDArray[np.float64]
Observations = SphereObservations | PositionObservations
JobCancelled = mf.Cancelled      # the callback asked to stop; nothing is stored
OBJECTIVES = ('relative', 'absolute')


@dataclass(frozen=True)
class JobInputs:
    """How a job identified: where the data came from and the solver settings."""

    source: str
    rows: int          # observations used
    solver: str
    loss: str
    objective: str     # 'relative' (spheres) or 'absolute' (a tracker)


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameters and how the fit went.

    ``params`` (P,) the whole model [m, rad], ``p_flange_tool`` (3,) the identified tool centre in
    the flange [m]; ``free`` the identified names (the model's, then tool_x, tool_y, tool_z),
    ``std`` their standard deviations sqrt(diag(s^2 (J^T J)^-1)) [m or rad] (inf: not
    determined). ``cost`` 0.5 f^2 sum(rho((r/f)^2)) [m^2], ``rms_m`` the RMS of the residuals
    [m]; ``iterations`` as the callback saw them (the start is 0); ``converged``: the solver
    met its stopping tolerances (else ``message`` starts with "did not converge"). ``extra``:
    'objective' ('relative' or 'absolute'), 'nuisance' {name: value} (sphere centres, base
    frame, the ball or marker) [m, rad].
    """

    params: Array
    p_flange_tool: Array
    free: tuple[str, ...]
    std: Array
    iterations: int
    cost: float
    rms_m: float
    solve_seconds: float
    message: str
    extra: dict = field(default_factory=dict)
    converged: bool = True


@dataclass(frozen=True)
class Outcome:
    """What a job found; store.records.KinematicRecord.from_outcome makes the stored record."""

    model: KinematicModel
    inputs: JobInputs
    result: IdentificationResult
    identifiability: mf.Identifiability
    free_values: Array                # identified values of result.free [m, rad]
    nominal_values: Array             # the same parameters of the nominal model [m, rad]
    validation: dict[str, dict]       # region -> {'nominal', 'calibrated'}: error_stats [m]
    table: str                        # the identified model as the paper's Table 6
    verdict: Verdict = Verdict()      # the gates' (module doc, steps 2-3)
    notes: tuple[str, ...] = ()       # parameters held at nominal and large ones, with why

    def summary(self) -> str:
        r = self.result
        parts = [] if self.verdict.passed else [self.verdict.line()]
        parts += [f'{len(r.free)} parameters identified, '
                 f'{len(self.identifiability.dropped)} dropped, RMS {r.rms_m * 1e3:.4f} mm in '
                 f'{r.solve_seconds:.2f} s ({r.iterations} iterations)']
        for region, table in self.validation.items():
            parts.append(f'{region}: max error {table["nominal"]["max_m"] * 1e3:.3f} -> '
                         f'{table["calibrated"]["max_m"] * 1e3:.3f} mm')
        return '; '.join(parts + list(self.notes))


@dataclass
class CalibrationJob:
    cell: Cell | None                 # for the nominal coupling offset (None: give p_flange_tool0)
    model: KinematicModel
    data: Observations
    source: str = ''                  # where the data came from (for the record)
    solver: str = 'lm'
    loss: str = 'soft_l1'
    objective: str | None = None      # from the data when None
    max_configs: int = 0              # 0: all rows; else an even subset
    validation: dict[str, PositionObservations] = field(default_factory=dict)
    p_flange_tool0: Array | None = None # nominal tool centre in the flange [m]
    solver_options: dict[str, Any] = field(default_factory=dict)
    bounds: DeviationBounds = field(default_factory=DeviationBounds)

    def __post_init__(self) -> None:
        if self.p_flange_tool0 is None:
            if self.cell is None or self.cell.spheres is None:
                raise ValueError('no nominal tool centre: give p_flange_tool0 or a cell with '
                                 'a spheres: T_flange_coupling')
            self.p_flange_tool0 = self.cell.spheres.T_flange_coupling[:3, 3].copy()
        self.p_flange_tool0 = np.asarray(self.p_flange_tool0, dtype=float)
        self.data = _subset(self.data, self.max_configs)

    def run(self, callback: Callable[[int, float, float], bool] | None = None) -> Outcome:
        """The module doc's steps; ``callback(iteration, cost, rms_m)`` as
        :func:`measurement_fit.calibrate`'s (False: JobCancelled). core.errors.Refusal for data
        the gates refuse before the solve, ValueError for data that cannot be fitted."""
        model, errors = self.model, self.error_model()
        calibration = mf.calibrate(errors, self.measurements(), loss=self.loss,
                                   bounds=self.bounds, solver=self.solver,
                                   options=self.solver_options or None, callback=callback)
        result = self._result(calibration)
        validation = {region: self.validate(result, data)
                      for region, data in self.validation.items()}
        free_values = np.concatenate([calibration.fit.values, result.p_flange_tool])
        nominal_values = np.concatenate([errors.start(calibration.fit.names), self.p_flange_tool0])
        verdict = Verdict(calibration.problems + tuple(
            p for region, t in validation.items() for p in gates.result_problems(
                True, t['nominal']['mean_m'], t['calibrated']['mean_m'],
                what=f'mean tracker error ({region})')))
        notes = tuple(f'held {h.name} at nominal: {h.reason}' for h in calibration.held) + \
            tuple(f'large: {note}' for note in calibration.large())
        return Outcome(model, self._inputs(), result, calibration.identifiability, free_values,
                       nominal_values, validation, table6(model, result.params), verdict,
                       notes)

    def error_model(self) -> mf.ErrorModel:
        return error_model(self.model)

    def measurements(self) -> Measurements:
        """The observations as the measurement kind they are (module doc, step 1)."""
        data, wanted = self.data, self.objective
        relative = isinstance(data, SphereObservations)
        if wanted is not None and wanted not in OBJECTIVES:
            raise ValueError(f'objective must be one of {OBJECTIVES}, got {wanted!r}')
        if wanted is not None and (wanted == 'relative') != relative:
            need = 'SphereObservations' if wanted == 'relative' else 'PositionObservations'
            raise ValueError(f'objective {wanted!r} needs {need}, got {type(data).__name__}')
        if relative:
            return sphere_measurements(data, self.p_flange_tool0)
        return Measurements('points', data.q, np.zeros(len(data.q), int), data.p,
                            ball=self.p_flange_tool0)

    def _result(self, calibration: mf.Calibration) -> IdentificationResult:
        fit, errors = calibration.fit, self.error_model()
        params, _ = errors.parameters(fit.names, fit.values)
        n, names = len(fit.names), fit.problem.kind.names
        tool = names.index('ball_x' if 'ball_x' in names else 'marker_0_x')
        std = fit.standard_deviations()
        solution = fit.solution
        return IdentificationResult(
            params, fit.nuisance[tool:tool + 3].copy(), fit.names + TOOL_NAMES,
            np.concatenate([std[:n], std[n + tool:n + tool + 3]]), solution.iterations,
            solution.cost, solution.rms_m, solution.seconds, solution.message,
            {'objective': self._objective(),
             'nuisance': dict(zip(names, (float(v) for v in fit.nuisance)))},
            solution.converged)

    def validate(self, result: IdentificationResult, data: PositionObservations) -> dict:
        """Table 5 rows for ``data``: nominal and calibrated, each registered by its best
        rigid fit to the tracker frame."""
        nominal = absolute_errors(self.model, self.model.nominal, self.p_flange_tool0, data.q,
                                  data.p)
        calibrated = absolute_errors(self.model, result.params, result.p_flange_tool, data.q,
                                     data.p)
        return {'nominal': {**error_stats(nominal), 'count': len(nominal)},
                'calibrated': {**error_stats(calibrated), 'count': len(calibrated)},
                'spread_mm': _spread_mm(
                    tool_frames(self.model, None, self.p_flange_tool0, data.q)[:, :3, 3])}

    def _objective(self) -> str:
        return 'relative' if isinstance(self.data, SphereObservations) else 'absolute'

    def _inputs(self) -> JobInputs:
        return JobInputs(self.source, len(self.data.q), self.solver, self.loss,
                         self._objective())


def error_model(model: KinematicModel) -> mf.ErrorModel:
    """A model's own error model: every row of a DH table, every joint origin of a URDF."""
    return mf.ErrorModel(model, 'mdh' if model.kind == 'mdh' else 'full')


def sphere_measurements(data: SphereObservations, p_flange_tool0: Array) -> Measurements:
    """Sphere couplings as the measurement kind ``spheres``, the coupling's centre the ball;
    distances between spheres the data touch."""
    present = set(data.spheres)
    return Measurements('spheres', data.q, data.sphere, ball=p_flange_tool0, distances=tuple(
        d for d in data.known_distances if d[0] in present and d[1] in present))


def free_parameters(model: KinematicModel, data: SphereObservations,
                    p_flange_tool0: Array) -> tuple[str, ...]:
    """What a CalibrationJob on ``data`` identifies: the identifiable parameters
    (:func:`measurement_fit.identifiable`), then tool_x, tool_y, tool_z (the ball)."""
    return mf.identifiable(error_model(model), sphere_measurements(data, p_flange_tool0)).kept \
        + TOOL_NAMES


def fit_spheres(model: KinematicModel, data: SphereObservations, p_flange_tool0: Array,
                free: tuple[str, ...]) -> tuple[Array, Array, mf.Fit]:
    """Least squares of the parameters named in ``free`` on sphere data, from the nominal
    model (tool_x, tool_y, tool_z: the ball, a nuisance unknown, always fitted), without the
    gates: (params (P,), p_flange_tool (3,), the fit). For planning and its benches."""
    errors = error_model(model)
    fit = mf.fit(errors, sphere_measurements(data, p_flange_tool0),
                 tuple(n for n in free if n not in TOOL_NAMES))
    return errors.parameters(fit.names, fit.values)[0], fit.nuisance[:3].copy(), fit


def _subset(data: Observations, limit: int) -> Observations:
    keep = even_subset(len(data.q), limit)
    if len(keep) == len(data.q):
        return data
    if isinstance(data, SphereObservations):
        return SphereObservations(data.q[keep], data.sphere[keep], data.known_distances)
    return PositionObservations(data.q[keep], data.p[keep])


def _spread_mm(p: Array) -> dict:
    """Mean, std, min, max per axis of points in the base frame [mm] (the paper's Tables 3-4)."""
    p = np.asarray(p) * 1e3
    return {axis: {'mean': float(p[:, i].mean()), 'std': float(p[:, i].std()),
                   'min': float(p[:, i].min()), 'max': float(p[:, i].max())}
            for i, axis in enumerate('xyz')}
