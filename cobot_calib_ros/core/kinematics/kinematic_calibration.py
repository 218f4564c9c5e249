"""One kinematic calibration, start to end: identifiability, solve, validate, the outcome.

The one place that strings the identification core together, used by the
``kinematic_identifier`` node (and through it by ``cobot-calib identify``):

1. Algorithm 1 (:func:`find_redundant`) on the calibration configurations themselves picks the
   identifiable parameters among all but the first joint's (tied to the world frame) plus the
   tool centre, with a rigid base motion held in the Jacobian: relative data cannot see it and
   the absolute objective fits it, so parameters equivalent to it go too. The tool centre is
   always kept: where an arm parameter and the tool are redundant (the last joint's d against
   tool_z), the difference is the coupling's mounting, and the arm stays nominal there, so
   another tool on the same flange (the probe) does not inherit the coupling's offset;
2. :func:`identify` with the chosen solver and loss;
3. validation: absolute errors against laser-tracker sets, nominal against calibrated, as the
   paper's Table 5; each model registered to the tracker by its own best rigid fit (a relative
   calibration has no world frame);
4. the gates (:mod:`.identification.gates`), as for a measurement file: the data plausible for
   the arm before the solve (a Refusal), then the verdict on the result: converged, every
   deviation inside ``bounds``, no worse than nominal on the validation sets. A result whose
   verdict did not pass is reported with it and never stored or made active;
5. the outcome, which the store turns into a record (store.records.KinematicRecord) and writes
   as JSON, YAML and a calibrated URDF.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification import gates
from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds, Verdict
from cobot_calib_ros.core.kinematics.identification.identifiability import (
    find_redundant, Identifiability)
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import (
    default_candidates, ParameterSet, tool_frames, TOOL_NAMES)
from cobot_calib_ros.core.kinematics.identification.solvers import (
    identify, IdentificationResult, NM_CONVERGED)
from cobot_calib_ros.core.kinematics.identification.validation import (
    absolute_errors, error_stats, table6)
from cobot_calib_ros.core.kinematics.model import KinematicModel
from cobot_calib_ros.core.kinematics.plans import even_subset

Array = NDArray[np.float64]
Observations = SphereObservations | PositionObservations
BASE_ROW_REASON = 'places joint 1 in the base: tied to the world frame (paper, section 3.1)'
# URDF models round pi/2 (the Sawyer's 1.57079632679): near-redundancies just above numpy's
# default rank tolerance would be kept at a condition number ~1e12 (find_redundant's note);
# measured on the mock Sawyer, 1e-8 still kept a set with condition 8e6 whose weak direction
# took 3 um of coupling noise to a 0.4 mrad tilt of the model; 1e-6 keeps condition ~1e3
ROUNDED_MODEL_RTOL = 1e-6


class JobCancelled(Exception):
    """The callback asked to stop; nothing is stored."""


@dataclass(frozen=True)
class JobInputs:
    """How a job identified: where the data came from and the solver settings."""

    source: str
    rows: int          # observations used
    solver: str
    loss: str
    objective: str     # 'relative' (spheres) or 'absolute' (a tracker)


@dataclass(frozen=True)
class Outcome:
    """What a job found; store.records.KinematicRecord.from_outcome makes the stored record."""

    model: KinematicModel
    inputs: JobInputs
    result: IdentificationResult
    identifiability: Identifiability
    free_values: Array                # identified values of result.free [m, rad]
    nominal_values: Array             # the same parameters of the nominal model [m, rad]
    validation: dict[str, dict]       # region -> {'nominal': stats, 'calibrated': stats}
    table: str                        # the identified model as the paper's Table 6
    verdict: Verdict = Verdict()      # the gates' (module doc, step 4)

    def summary(self) -> str:
        r = self.result
        parts = [] if self.verdict.passed else [self.verdict.line()]
        parts += [f'{len(r.free)} parameters identified, '
                 f'{len(self.identifiability.dropped)} dropped, RMS {r.rms_m * 1e3:.4f} mm in '
                 f'{r.solve_seconds:.2f} s ({r.iterations} iterations)']
        for region, table in self.validation.items():
            parts.append(f'{region}: max error {table["nominal"]["max_mm"]:.3f} -> '
                         f'{table["calibrated"]["max_mm"]:.3f} mm')
        return '; '.join(parts)


@dataclass
class CalibrationJob:
    cell: Cell | None                 # for the nominal coupling offset (None: give tool_xyz0)
    model: KinematicModel
    data: Observations
    source: str = ''                  # where the data came from (for the record)
    solver: str = 'lm'
    loss: str = 'soft_l1'
    objective: str | None = None      # from the data when None
    max_configs: int = 0              # 0: all rows; else an even subset
    validation: dict[str, PositionObservations] = field(default_factory=dict)
    tool_xyz0: Array | None = None    # nominal tool centre in the flange [m]
    solver_options: dict[str, Any] = field(default_factory=dict)
    bounds: DeviationBounds = field(default_factory=DeviationBounds)

    def __post_init__(self) -> None:
        if self.tool_xyz0 is None:
            if self.cell is None or self.cell.spheres is None:
                raise ValueError('no nominal tool centre: give tool_xyz0 or a cell with '
                                 'a spheres: coupling_offset')
            self.tool_xyz0 = self.cell.spheres.coupling_offset[:3, 3].copy()
        self.tool_xyz0 = np.asarray(self.tool_xyz0, dtype=float)
        self.data = _subset(self.data, self.max_configs)

    def run(self, callback: Callable[[int, float, float], bool] | None = None) -> Outcome:
        model = self.model
        gates.refuse(self.data_problems())
        identifiability = identifiable(model, self.data.q, self.tool_xyz0)
        parameter_set = ParameterSet(model, identifiability.kept)
        options = self.solver_options or (NM_CONVERGED if self.solver == 'nelder-mead'
                                          else {})
        result = identify(parameter_set, self.data, tool_xyz0=self.tool_xyz0,
                          solver=self.solver, loss=self.loss, objective=self.objective,
                          callback=callback, **options)
        if result.code == ErrorCode.CANCELED:
            raise JobCancelled(result.message)
        if not (np.all(np.isfinite(result.params)) and np.all(np.isfinite(result.tool_xyz))):
            raise ValueError(f'the solver returned non-finite parameters: {result.message}')
        validation = {region: self.validate(result, data)
                      for region, data in self.validation.items()}
        free_values = parameter_set.values(result.params, result.tool_xyz)
        nominal_values = parameter_set.values(model.nominal, self.tool_xyz0)
        table = table6(model, result.params)
        verdict = Verdict(tuple(
            gates.at_bounds(model, result.free, free_values - nominal_values, self.bounds)
            + ([] if result.converged else [f'the solver did not converge ({result.message}): '
                                            'the model may be far from the optimum'])
            + [p for region, t in validation.items() for p in gates.result_problems(
                True, t['nominal']['mean_mm'] * 1e-3, t['calibrated']['mean_mm'] * 1e-3,
                what=f'mean tracker error ({region})')]))
        return Outcome(model, self._inputs(result), result, identifiability, free_values,
                       nominal_values, validation, table, verdict)

    def data_problems(self) -> list[str]:
        """Gate 1: joint values inside the arm's limits; known sphere distances like those
        of the centres the nominal arm reaches."""
        problems = gates.joint_problems(self.model, self.data.q)
        if problems or not isinstance(self.data, SphereObservations):
            return problems
        p = tool_frames(self.model, None, self.tool_xyz0, self.data.q)[:, :3, 3]
        ids = np.unique(self.data.sphere)
        centres = {int(i): p[self.data.sphere == i].mean(axis=0) for i in ids}
        return gates.distance_problems(self.data.known_distances, centres)

    def validate(self, result: IdentificationResult, data: PositionObservations) -> dict:
        """Table 5 rows for ``data``: nominal and calibrated, each registered by its best
        rigid fit to the tracker frame."""
        nominal = absolute_errors(self.model, self.model.nominal, self.tool_xyz0, data.q, data.p)
        calibrated = absolute_errors(self.model, result.params, result.tool_xyz, data.q, data.p)
        return {'nominal': {**error_stats(nominal), 'count': len(nominal)},
                'calibrated': {**error_stats(calibrated), 'count': len(calibrated)},
                'spread_mm': _spread_mm(
                    tool_frames(self.model, None, self.tool_xyz0, data.q)[:, :3, 3])}

    def _inputs(self, result: IdentificationResult) -> JobInputs:
        objective = result.extra.get('objective') or self.objective or (
            'relative' if isinstance(self.data, SphereObservations) else 'absolute')
        return JobInputs(self.source, len(self.data.q), self.solver, self.loss, objective)


def identifiable(model: KinematicModel, q: Array, tool_xyz0: Array) -> Identifiability:
    """Step 1 of the module doc: Algorithm 1 on configurations q (m, n) [rad]."""
    base_row = model.parameter_names[:model.fields_per_joint]
    return find_redundant(
        model, q, tool_xyz0, default_candidates(model),
        excluded={name: BASE_ROW_REASON for name in base_row}, base_frame=True,
        rank_rtol=ROUNDED_MODEL_RTOL if model.kind == 'origin' else None, keep=TOOL_NAMES)


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
