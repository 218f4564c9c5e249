"""The intrinsics calibration's one api (issue 39.2): the camera_info YAML's one writer, the
record stored and activated, for camera_calibrator's goal and the offline ``cobot-calib
intrinsics SOURCE`` alike; and the client side of ``calibrate_intrinsics`` (``cobot-calib
intrinsics --planned / --live``).

- :func:`calibrate_on_cell`: the node's goal: a folder of images, planned views or live views
  (core.landmarks.intrinsics_capture's procedures), then :func:`store_run`;
- :func:`store_run`: the record (store.records.IntrinsicsRecord) of a fit, its camera_info
  YAML written atomically (default ``<data_dir>/intrinsics/<id>.yaml``) and, given a
  repository, stored and made active for its camera when its gate passes (else kept as
  rejected: IMPLAUSIBLE_FIT);
- :func:`calibrate_on_suite`: send the goal and wait.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.landmarks.camera import camera_info_yaml
from cobot_calib_ros.core.landmarks.intrinsics import MODELS
from cobot_calib_ros.core.landmarks.intrinsics_capture import (calibrate_images,
                                                                calibrate_live,
                                                                calibrate_planned,
                                                                IntrinsicsRun, Progress)
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.core.robot_port import Cancelled, never
from cobot_calib_ros.loaders.images import folder_images
from cobot_calib_ros.store.files import atomic_write_text, ensure_dir
from cobot_calib_ros.store.records import IntrinsicsRecord

DEFAULT_VIEWS = 20
SUITE_TIMEOUT = 1800.0     # [s] for calibrate_intrinsics on the suite (live: up to live_timeout)


@dataclass(frozen=True)
class IntrinsicsRequest:
    """What a calibrate_intrinsics goal asks for (defaults filled): ``source`` a folder of
    images ('' : the camera), ``planned`` (the arm moves the camera) or live."""

    model: str = 'plumb_bob'
    count: int = DEFAULT_VIEWS
    source: str = ''
    planned: bool = False
    seed: int = 0
    image_timeout: float = 5.0     # [s]


@dataclass(frozen=True)
class IntrinsicsOutcome:
    """A fit written and stored: ``code`` SUCCESS (active) or IMPLAUSIBLE_FIT (stored as
    rejected, not active; or not stored: no repository), ``message`` what to tell the user,
    ``not_active_because`` the gate's reason. Truthy (a Failure is not)."""

    record: IntrinsicsRecord
    run: IntrinsicsRun
    active: bool
    not_active_because: str
    code: ErrorCode
    message: str


def write_camera_info(camera, path: Path) -> Path:
    """The ROS camera_info YAML of ``camera`` (a core CameraModel) at ``path``, atomically:
    the one writer of that file."""
    path = Path(path)
    ensure_dir(path.parent)
    atomic_write_text(path, camera_info_yaml(camera))
    return path


def store_run(run: IntrinsicsRun, *, source: str, board: str, repo=None, data_dir=None,
              yaml_path: Path | None = None, wall_ns: int | None = None
              ) -> IntrinsicsOutcome | Failure:
    """Write ``run``'s camera_info YAML (``yaml_path``, default ``<data_dir>/intrinsics/
    <record id>.yaml``) and, with ``repo`` (a store.Repository), store its record and make it
    the camera's active intrinsics if its gate passes. STORAGE_FAILED when either cannot be
    written."""
    fit = run.fit
    record = IntrinsicsRecord.from_fit(fit, camera=fit.camera.name, source=source, board=board,
                                       views=[v.name for v in run.views], wall_ns=wall_ns)
    try:
        path = write_camera_info(fit.camera, yaml_path if yaml_path is not None else
                                 Path(data_dir) / 'intrinsics' / f'{record.id}.yaml')
        record.result.yaml_path = str(path.resolve())
        activation = None if repo is None else repo.intrinsics.save_and_activate(record)
    except Refusal as e:                          # another cell's (store.cells)
        return e.failure
    except (OSError, ValueError) as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the intrinsics: {e}')
    active = bool(activation)
    reason = fit.gate_problem if activation is None else activation.reason
    K = fit.camera.K
    summary = (f'{record.id}: fx {K[0, 0]:.3f} fy {K[1, 1]:.3f} cx {K[0, 2]:.3f} '
               f'cy {K[1, 2]:.3f} px, rms {fit.rms_px:.4f} px, held out '
               f'{fit.heldout_rms_px:.4f} px, {fit.views_used} views')
    if activation is not None and not active:
        return IntrinsicsOutcome(record, run, False, reason, ErrorCode.IMPLAUSIBLE_FIT,
                                 f'{summary}; stored as rejected, not active: {reason}')
    return IntrinsicsOutcome(record, run, active, reason, ErrorCode.SUCCESS,
                             f'{summary}; active' if active else summary)


def _request_problem(request: IntrinsicsRequest, cell) -> Failure | None:
    if request.model not in MODELS or not 4 <= request.count <= 200:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'model must be one of {", ".join(MODELS)} (got {request.model!r}) and '
                       f'views 4..200 (0 = {DEFAULT_VIEWS}), got {request.count}')
    if cell.camera is None or cell.landmarks is None or not cell.landmarks.board:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'cell {cell.name!r} has no wrist camera or no board; add camera: and '
                       'landmarks: board: to the cell file')
    if request.source and not Path(request.source).is_dir():
        return Failure(ErrorCode.INVALID_INPUT,
                       f'source {request.source!r} is not a folder of images (a bag: run '
                       '`cobot-calib intrinsics BAG`)')
    return None


def calibrate_on_cell(request: IntrinsicsRequest, cell, kinematic_model, robot, images, *,
                      T_base_user: Callable[[], object], repo, data_dir, wall_ns: int,
                      live_deadline: Callable[[], bool], cancelled: Cancelled = never,
                      progress: Progress | None = None) -> IntrinsicsOutcome | Failure:
    """camera_calibrator's goal: ``request.source``'s images, or the cell's camera (RobotPort
    ``robot`` and ImagePort ``images``) through planned views (the board where
    ``T_base_user()`` puts it: ValueError saying what to do) or live ones until
    ``live_deadline()``; fitted and stored (:func:`store_run`, the YAML under ``data_dir``)."""
    problem = _request_problem(request, cell)
    if problem is not None:
        return problem
    common = dict(model=request.model, image_timeout=request.image_timeout,
                  cancelled=cancelled, progress=progress)
    if request.source:
        run = calibrate_images(folder_images(request.source), BoardSpec.parse(
            cell.landmarks.board), model=request.model, name=cell.camera.frame_id,
            source=request.source)
    elif request.planned:
        try:
            where = T_base_user()
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, str(e))
        run = calibrate_planned(cell, kinematic_model, robot, images, count=request.count,
                                T_base_user=where, seed=request.seed, **common)
    else:
        run = calibrate_live(cell, images, count=request.count, deadline=live_deadline,
                             **common)
    if not run:
        return run
    return store_run(run, source=request.source or 'live',
                     board=str(BoardSpec.parse(cell.landmarks.board)),
                     repo=repo, data_dir=data_dir, wall_ns=wall_ns)


def calibrate_on_suite(node, goal, feedback=None, timeout: float = SUITE_TIMEOUT,
                       executor=None):
    """Run camera_calibrator's calibrate_intrinsics with ``goal`` to its end; the result
    (CallError if the action is missing or does not finish in time)."""
    from cobot_calib_msgs.action import CalibrateIntrinsics
    from cobot_calib_ros.ros.calls import run_action_once
    return run_action_once(node, CalibrateIntrinsics, 'calibrate_intrinsics', goal, timeout,
                           feedback, executor)
