"""Typed records: the one schema of what each calibration kind and each trial keeps.

Every record is a dataclass with ``to_dict()`` (the mapping the folder store writes as JSON or
YAML: the keys the files have always had) and ``from_dict()`` (reads those files, older ones
included). Keys a record does not know are kept in ``extra`` and written back unchanged, so a
newer file survives an older reader. Arrays may be given as numpy arrays; ``to_dict`` turns
them into plain lists. Lengths are in metres unless a name says ``_mm``.

Gate: every calibration record carries ``gate_problem`` ('' : it passes the gate of its kind,
else why not). The builder of a record sets it with its kind's criterion (e.g. a hand-eye
whose residual is beyond what its views' noise allows); the store never activates a record
with a gate problem (see store.repository). The key is written only when it is not empty.

Provenance: every calibration record carries ``measured_through`` (kind -> the id of the result
it was measured through, 'nominal' for the cell's own value; store.rigs reads it, core.provenance
says when it is stale); the key is left out where it was not recorded, and a record without it
reads as {} (unknown provenance).

Cell: every calibration record names the cell it was made on (``cell``) and its robot
(``robot``); the store of a cell sets both when it saves (store.cells). Records written before
that lack them (hand-eye records always named their cell file).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, MISSING
import time
from typing import Any, ClassVar

import numpy as np

from cobot_calib_ros.core import user_frame
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.store.files import to_plain
from cobot_calib_ros.store.renamed import with_current_names

OMITTED_WHEN_EMPTY = ('gate_problem', 'hand_eye', 'tcp', 'cell', 'robot')  # keys older files lack
OMITTED_WHEN_NONE = frozenset({'converged', 'measured_through'})   # keys older records lack


@dataclass(kw_only=True)
class Record:
    """Base of the typed records: ``to_dict`` / ``from_dict`` over the dataclass fields;
    ``NESTED`` names the fields that hold another record (None allowed)."""

    NESTED: ClassVar[dict[str, type[Record]]] = {}
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == 'extra' or (f.name in OMITTED_WHEN_EMPTY and not value) or (
                    f.name in OMITTED_WHEN_NONE and value is None):
                continue
            out[f.name] = value.to_dict() if isinstance(value, Record) else to_plain(value)
        return {**out, **to_plain(self.extra)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]):
        """The record of a stored mapping; ValueError naming the keys it lacks."""
        if not isinstance(data, Mapping):
            raise ValueError(f'{cls.__name__}: expected a mapping, got {type(data).__name__}')
        data = with_current_names(data)
        known = {f.name: f for f in fields(cls) if f.name != 'extra'}
        required = [name for name, f in known.items() if _required(f)]
        missing = [name for name in required if name not in data]
        if missing:
            raise ValueError(f'{cls.__name__}: missing keys {missing}')
        kwargs = {}
        for name in known.keys() & data.keys():
            nested, value = cls.NESTED.get(name), data[name]
            kwargs[name] = nested.from_dict(value) if nested and value is not None else value
        return cls(**kwargs, extra={k: v for k, v in data.items() if k not in known})


def _required(f) -> bool:
    return f.default is MISSING and f.default_factory is MISSING


# -- user frame (user_frame_solver) ------------------------------------------------------------

@dataclass(kw_only=True)
class SurfaceRecord(Record):
    """The table's height correction fitted beside a user frame (core.user_frame)."""

    valid: bool
    powers_x: list[int]
    powers_y: list[int]
    coefficients: Any          # (k,) [m]
    rms_before: float          # [m]
    rms_after: float           # [m]

    def model(self) -> user_frame.SurfaceModel | None:
        """The core surface model, None if the fit was not valid."""
        if not self.valid:
            return None
        return user_frame.SurfaceModel(tuple(self.powers_x), tuple(self.powers_y),
                                       np.array(self.coefficients, dtype=float),
                                       self.rms_before, self.rms_after, ErrorCode.SUCCESS)


@dataclass(kw_only=True)
class UserFrameInputs(Record):
    point_names: list[str]
    points_user: Any           # (N, 3) nominal points in the user frame [m]
    points_base: Any           # (N, 3) the same points measured in the base frame [m]


@dataclass(kw_only=True)
class UserFrameResult(Record):
    """A core.user_frame.FrameFit as stored (rms: the RMS residual [m])."""

    NESTED = {'surface': SurfaceRecord}
    T_base_user: Any           # (4, 4)
    M: Any                     # (4, 4) the fitted (possibly affine) matrix
    residuals: Any             # (N, 3) [m]
    rms: float                 # [m]
    max_residual: float        # [m]
    condition_number: float
    collinearity: float
    covariance: Any            # (6, 6)
    scale: Any                 # (3,)
    shear: Any                 # (3,)
    outliers: list[int] = field(default_factory=list)
    message: str = ''
    surface: SurfaceRecord | None = None


@dataclass(kw_only=True)
class UserFrameRecord(Record):
    """One user-frame calibration. ``stamp_ns`` is ROS time; the id (a file name) comes from
    the wall clock so that it stays unique under a paused sim clock."""

    NESTED = {'inputs': UserFrameInputs, 'result': UserFrameResult}
    id: str
    stamp_ns: int
    method: str
    kinematics: str = ''       # the kinematic model that measured the points ('' : unknown)
    hand_eye: str = ''         # landmark methods: the hand-eye calibration used
    tcp: str = ''              # touched points: the TCP calibration of the tool that touched
    #                            them ('nominal': the cell's T_flange_tool; '' : not touched, or
    #                            stored before records named it)
    base_frame: str
    user_frame: str
    inputs: UserFrameInputs
    result: UserFrameResult
    gate_problem: str = ''
    cell: str = ''              # set by the cell's store (store.cells)
    robot: str = ''
    measured_through: dict[str, str] | None = None   # kind -> id; None: not recorded

    @classmethod
    def from_fit(cls, fit: user_frame.FrameFit, surface: user_frame.SurfaceModel | None,
                 names: list[str], p_user, p_base, frames_: tuple[str, str], stamp_ns: int,
                 kinematics: str = '', hand_eye: str = '', tcp: str = '',
                 measured_through: dict[str, str] | None = None) -> UserFrameRecord:
        """The record of a fit (and its optional surface) of ``names``' points, measured
        through ``measured_through`` (kind -> id)."""
        stored_surface = None if surface is None else SurfaceRecord(
            valid=bool(surface), powers_x=surface.powers_x, powers_y=surface.powers_y,
            coefficients=surface.coefficients, rms_before=surface.rms_before,
            rms_after=surface.rms_after)
        return cls(
            id=record_id(fit.method), stamp_ns=stamp_ns, method=fit.method,
            kinematics=kinematics, hand_eye=hand_eye, tcp=tcp, base_frame=frames_[0],
            user_frame=frames_[1], measured_through=measured_through,
            inputs=UserFrameInputs(point_names=list(names), points_user=p_user,
                                   points_base=p_base),
            result=UserFrameResult(
                T_base_user=fit.T_base_user, M=fit.M, residuals=fit.residuals, rms=fit.rms,
                max_residual=fit.max_residual, condition_number=fit.condition_number,
                collinearity=fit.collinearity, covariance=fit.covariance, scale=fit.scale,
                shear=fit.shear, outliers=list(fit.outliers), message=fit.message,
                surface=stored_surface))

    def surface_model(self) -> user_frame.SurfaceModel | None:
        """The valid surface correction stored with the frame, else None."""
        return None if self.result.surface is None else self.result.surface.model()


# -- hand-eye (hand_eye_calibrator) ------------------------------------------------------------

@dataclass(kw_only=True)
class HandEyeInputs(Record):
    joints: Any                # (V, n) joints of each used view [rad]
    T_base_flange: Any         # (V, 4, 4)
    T_optical_board: Any       # (V, 4, 4)
    board_covariances: Any     # (V, 6, 6)
    skipped: Any               # the views skipped, with why
    planned_views: int


@dataclass(kw_only=True)
class HandEyeResult(Record):
    T_flange_optical: Any      # (4, 4)
    T_base_board: Any          # (4, 4)
    initial_T_flange_optical: Any
    residual_mm: float
    residual_mrad: float
    residuals_mm: Any          # (V,)
    residuals_mrad: Any        # (V,)
    covariance: Any            # (6, 6)
    views_used: int


@dataclass(kw_only=True)
class HandEyeRecord(Record):
    NESTED = {'inputs': HandEyeInputs, 'result': HandEyeResult}
    id: str
    stamp_ns: int
    method: str
    kinematics: str = 'nominal'
    flange_frame: str
    camera_frame: str
    cell: str
    inputs: HandEyeInputs
    result: HandEyeResult
    gate_problem: str = ''
    robot: str = ''              # set by the cell's store (store.cells)
    measured_through: dict[str, str] | None = None   # kind -> id; None: not recorded


# -- tool centre point (tcp_calibrator) --------------------------------------------------------

@dataclass(kw_only=True)
class TcpInputs(Record):
    point_name: str            # the fixed point of the cell the tip was brought to
    labels: list[str]          # each touch: 'approach 1'.., 'z elongator', 'x elongator'
    joints: Any                # (N, n) captured joints of each touch [rad]
    T_base_flange: Any         # (N, 4, 4) their flange poses by the kinematics used [m]
    tilt: float = 0.0          # [rad] of the planned approaches from the first
    elongation: float = 0.0    # [m] of the elongator points (0: none)


@dataclass(kw_only=True)
class TcpResult(Record):
    """A core.tcp.TcpSolution as stored."""

    T_flange_tool: Any         # (4, 4) rotation identity for orientation_method 'none'
    fixed_point: Any           # (3,) in the base frame [m]
    orientation_method: str    # 'none' (position only), 'z', 'zx'
    mean_residual_mm: float
    max_residual_mm: float
    residuals_mm: Any          # (approaches,) each tip's distance from the fixed point
    condition: float
    covariance: Any            # (3, 3) of the TCP position [m^2]
    linear_t: Any              # (3,) the algebraic solution before the refinement [m]
    approaches: int


@dataclass(kw_only=True)
class TcpRecord(Record):
    """One TCP calibration of ``tool`` (activation is per tool; the cell's own tool is named
    by its tool_frame)."""

    NESTED = {'inputs': TcpInputs, 'result': TcpResult}
    id: str
    stamp_ns: int
    method: str                # e.g. 'tcp-6-point-z'
    tool: str
    kinematics: str = 'nominal'  # the kinematic calibration the flange poses came from
    inputs: TcpInputs
    result: TcpResult
    gate_problem: str = ''
    cell: str = ''               # set by the cell's store (store.cells)
    robot: str = ''
    measured_through: dict[str, str] | None = None   # kind -> id; None: not recorded

    @classmethod
    def from_solution(cls, solution, tool: str, point_name: str, labels: list[str], joints,
                      flange, stamp_ns: int, kinematics: str = 'nominal', tilt: float = 0.0,
                      elongation: float = 0.0, gate_problem: str = '',
                      measured_through: dict[str, str] | None = None) -> TcpRecord:
        """The record of a core.tcp.TcpSolution of ``tool`` from the touches' joints and
        flange poses (by the kinematics ``measured_through`` names)."""
        position = solution.position
        n = len(position.residuals)
        method = f'tcp-{n}-point' + ('' if solution.method == 'none' else f'-{solution.method}')
        return cls(
            id=record_id(f'tcp-{tool}'), stamp_ns=stamp_ns, method=method, tool=tool,
            kinematics=kinematics, gate_problem=gate_problem,
            measured_through=dict(measured_through or {'kinematics': kinematics}),
            inputs=TcpInputs(point_name=point_name, labels=list(labels), joints=joints,
                             T_base_flange=flange, tilt=tilt, elongation=elongation),
            result=TcpResult(T_flange_tool=solution.T_flange_tool, fixed_point=position.c,
                             orientation_method=solution.method,
                             mean_residual_mm=position.mean_residual_m * 1e3,
                             max_residual_mm=position.max_residual_m * 1e3,
                             residuals_mm=position.distances * 1e3,
                             condition=position.condition,
                             covariance=position.covariance[:3, :3],
                             linear_t=position.linear[:3], approaches=n))
# -- camera intrinsics (cobot-calib intrinsics, camera_calibrator) ----------------------------

@dataclass(kw_only=True)
class IntrinsicsInputs(Record):
    source: str                # a folder, a bag, a topic
    board: str                 # the board spec the corners belong to
    image_width: int
    image_height: int
    views: list[str]           # the views given (image files, stamps)


@dataclass(kw_only=True)
class IntrinsicsResult(Record):
    """A core.landmarks.intrinsics.IntrinsicsFit as stored (errors [px]; held out None when
    the views were too few to hold any out)."""

    camera_matrix: Any         # (3, 3) [px]
    distortion_model: str
    distortion_coefficients: Any
    rms_px: float
    heldout_rms_px: float | None
    view_rms_px: dict[str, float]
    outlier_views: list[str]
    views_used: int
    coverage: float            # fraction of the image's grid cells holding corners
    missing: str = ''          # what the views still lack ('' : nothing)
    yaml_path: str = ''        # the camera_info YAML written


@dataclass(kw_only=True)
class IntrinsicsRecord(Record):
    """One intrinsics calibration of ``camera`` (its name: the optical frame); activation is
    per camera."""

    NESTED = {'inputs': IntrinsicsInputs, 'result': IntrinsicsResult}
    id: str
    stamp_ns: int
    method: str                # the distortion model
    camera: str
    inputs: IntrinsicsInputs
    result: IntrinsicsResult
    gate_problem: str = ''
    cell: str = ''              # set by the cell's store (store.cells)
    robot: str = ''
    measured_through: dict[str, str] | None = None   # kind -> id; None: not recorded

    @classmethod
    def from_fit(cls, fit, *, camera: str, source: str, board: str, views: list[str],
                 yaml_path: str = '', wall_ns: int | None = None) -> IntrinsicsRecord:
        """The record of a core IntrinsicsFit, stamped with the wall clock (``wall_ns``,
        default now)."""
        wall_ns = time.time_ns() if wall_ns is None else wall_ns
        cam = fit.camera
        heldout = float(fit.heldout_rms_px)
        return cls(
            id=record_id(f'intrinsics-{cam.distortion_model}', wall_ns), stamp_ns=wall_ns,
            method=cam.distortion_model, camera=camera,
            inputs=IntrinsicsInputs(source=source, board=board, image_width=cam.width,
                                    image_height=cam.height, views=list(views)),
            result=IntrinsicsResult(
                camera_matrix=cam.K, distortion_model=cam.distortion_model,
                distortion_coefficients=cam.D, rms_px=fit.rms_px,
                heldout_rms_px=heldout if np.isfinite(heldout) else None,
                view_rms_px=dict(fit.view_rms_px), outlier_views=list(fit.outlier_views),
                views_used=fit.views_used, coverage=fit.coverage.fraction,
                missing=fit.coverage.message, yaml_path=yaml_path),
            gate_problem=fit.gate_problem, measured_through={})   # the board only

    def camera_model(self):
        """The core.landmarks.camera.CameraModel of these intrinsics."""
        from cobot_calib_ros.core.landmarks.camera import CameraModel
        r = self.result
        return CameraModel(self.inputs.image_width, self.inputs.image_height,
                           np.asarray(r.camera_matrix, dtype=float),
                           np.asarray(r.distortion_coefficients, dtype=float),
                           r.distortion_model, self.camera)


def active_intrinsics(repo, camera: str):
    """The CameraModel of ``camera``'s active intrinsics in ``repo`` (a store.Repository),
    None when it has none (the nominal CameraInfo then holds)."""
    plain = repo.intrinsics.active(camera)
    return None if plain is None else IntrinsicsRecord.from_dict(plain).camera_model()


# -- kinematic calibration (kinematic_identifier) ----------------------------------------------

@dataclass(kw_only=True)
class KinematicInputs(Record):
    source: str
    rows: int = 0
    solver: str = ''
    loss: str = ''
    objective: str = ''


@dataclass(kw_only=True)
class KinematicResult(Record):
    """What identification found; only the chain's parameters are needed to use it."""

    parameter_names: list[str]
    params: Any                # (P,) the full parameter vector of the model
    p_flange_tool: Any = None  # (3,) [m]
    free: list[str] = field(default_factory=list)
    values: Any = None
    std: Any = None
    dropped: list[dict[str, str]] = field(default_factory=list)
    rank: int = 0              # independent parameters identified: len(free)
    condition_number: float = 0.0
    rms_m: float = 0.0
    iterations: int = 0
    solve_seconds: float = 0.0
    message: str = ''
    # False: a cap stopped the solver (message: 'did not converge'); None: stored before
    # convergence was recorded (5252a67), written back without the key
    converged: bool | None = None
    validation: dict[str, Any] = field(default_factory=dict)
    table6: str = ''


@dataclass(kw_only=True)
class KinematicRecord(Record):
    """One kinematic calibration of ``robot`` (a model name); activation is per robot."""

    NESTED = {'inputs': KinematicInputs, 'result': KinematicResult}
    id: str
    stamp_ns: int
    method: str
    robot: str
    inputs: KinematicInputs
    result: KinematicResult
    gate_problem: str = ''
    cell: str = ''               # set by the cell's store (store.cells)
    measured_through: dict[str, str] | None = None   # kind -> id; None: not recorded

    @classmethod
    def from_outcome(cls, outcome, wall_ns: int | None = None,
                     measured_through: dict[str, str] | None = None) -> KinematicRecord:
        """The record of a core CalibrationJob outcome. Stamped with the wall clock (``wall_ns``,
        default now): identification runs offline, with no ROS clock. ``measured_through``:
        the TCP its measurements were taken at, {} (the default) when they carry their own
        marker (the sphere coupling, a tracker's target)."""
        wall_ns = time.time_ns() if wall_ns is None else wall_ns
        job, result = outcome.inputs, outcome.result
        return cls(
            id=record_id(job.solver, wall_ns), stamp_ns=wall_ns,
            method=f'{job.objective}-{job.solver}', robot=outcome.model.name,
            measured_through=dict(measured_through or {}),
            inputs=KinematicInputs(source=job.source, rows=job.rows, solver=job.solver,
                                   loss=job.loss, objective=job.objective),
            result=KinematicResult(
                parameter_names=list(outcome.model.parameter_names), params=result.params,
                p_flange_tool=result.p_flange_tool, free=list(result.free),
                values=outcome.free_values,
                std=result.std,
                dropped=[{'name': d.name, 'reason': d.reason}
                         for d in outcome.identifiability.dropped],
                rank=len(result.free),
                condition_number=outcome.identifiability.condition_number,
                rms_m=result.rms_m, iterations=result.iterations,
                solve_seconds=result.solve_seconds, message=result.message,
                converged=result.converged, validation=outcome.validation,
                table6=outcome.table))


    @classmethod
    def from_report(cls, report: dict, model, params, wall_ns: int | None = None,
                    unseen: list[dict] | None = None) -> KinematicRecord:
        """The record of a measurement file's (or MUKCa folder's) identification report
        (core measurement_fit.identify_measurements, api.identification) whose model
        parameters are ``params`` (P,) of ``model``: held-out figures as its validation, the
        verdict's problems as its gate problem, ``unseen``: the parameters the measurement
        cannot see (kept nominal), and what they affect. Its measurement carries its own
        markers or balls, so it was measured through nothing (``measured_through`` {})."""
        wall_ns = time.time_ns() if wall_ns is None else wall_ns
        identified = report['identified']
        kind = report['measurement']
        record = cls(
            id=record_id(f'{kind}-{report["model"]}', wall_ns), stamp_ns=wall_ns,
            method=f'{kind}-{report["model"]}', robot=model.name,
            inputs=KinematicInputs(source=str(report.get('source', '')), rows=report['rows'],
                                   solver='lm', loss=report['loss'],
                                   objective='relative' if kind in ('spheres', 'plane')
                                   else 'absolute'),
            result=KinematicResult(
                parameter_names=list(model.parameter_names), params=params,
                free=[p['name'] for p in identified],
                values=[p['value'] for p in identified],
                std=[p['std'] for p in identified] if all('std' in p for p in identified)
                else None, dropped=list(report['dropped']),
                rank=len(identified), condition_number=report['condition_number'],
                rms_m=report['training']['rmse_mm'] * 1e-3, converged=report['converged'],
                validation={'held_out': report['held_out'], 'noise_mm': report['noise_mm'],
                            **{k: report[k] for k in ('validation',) if k in report}}),
            gate_problem='; '.join(report['verdict']['problems']))
        record.extra.update(measured_through={}, unseen=list(unseen or ()))
        return record

# -- repeatability trial (repeatability_trial) -------------------------------------------------

@dataclass(kw_only=True)
class TrialSetup(Record):
    """What a new trial is asked to do (the start of its ``trial.yaml``; the trial store adds
    id, layout, status and stamps)."""

    method: str
    axis: str
    cycles_total: int
    point_names: list[str]


# -- quick health checks (cobot-calib check) ---------------------------------------------------

def check_record(check, method: str, against: str, stamp_ns: int | None = None,
                 wall_ns: int | None = None) -> dict[str, Any]:
    """The stored result of a core.health_checks check (``method``: 'user_frame' or
    'kinematics') made against calibration ``against`` ('nominal': none): never activated (a
    check changes no calibration)."""
    wall_ns = time.time_ns() if wall_ns is None else wall_ns
    inputs, result = check.stored()
    return to_plain({'id': record_id(f'check-{method}', wall_ns),
                     'stamp_ns': wall_ns if stamp_ns is None else stamp_ns, 'method': method,
                     'inputs': {'against': against, **inputs}, 'result': result})
