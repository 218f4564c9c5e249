"""A user-frame calibration, measured, stored and made active: the one path of the
calibrate_user_frame service (user_frame_solver, live over the robot and camera ports) and of
`cobot-calib user-frame --points` (api.user_frame_file, offline), and the activate / retire
choice of set_active_calibration.

The measurement is core.user_frame.procedure's; here: which kinematics, TCP and hand-eye it is
measured through (the cell's rig, store.rigs), the record, and one activation rule (saved, then
active if it passes its gate: store.calibrations.save_and_activate).
"""
from __future__ import annotations

from collections.abc import Callable
import contextlib
from dataclasses import dataclass, field

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.provenance import missing_prerequisites
from cobot_calib_ros.core.robot_port import Cancelled, never
from cobot_calib_ros.core.user_frame import landmarks as landmark_frames
from cobot_calib_ros.core.user_frame import procedure
from cobot_calib_ros.core.user_frame.procedure import FrameMeasurement, Gate
from cobot_calib_ros.store.records import UserFrameRecord
from cobot_calib_ros.store.rigs import rig_of


@dataclass(frozen=True)
class Request:
    """What to calibrate. Points given (``p_user`` and ``p_base`` [m], N each) are fitted as
    they are; else the cell's ``names`` are touched over the robot (or their ``joints`` given,
    one per name [rad]) and mapped through ``kinematics`` and the active TCP; a landmark
    ``method`` looks at the cell's fiducials instead."""

    method: str = 'rigid'
    names: tuple[str, ...] = ()
    p_user: np.ndarray | None = None
    p_base: np.ndarray | None = None
    joints: list | None = None
    kinematics: str = 'active'
    frames: tuple[str, str] = ('base_link', 'user_frame')     # (base, user) frame ids
    gate: Gate = field(default_factory=Gate)
    capture_duration: float = procedure.CAPTURE_DURATION      # [s]
    store: bool = True


@dataclass(frozen=True)
class Calibrated:
    """A calibration that passed its gate: its record (dict), the measurement, what it was
    measured through, the calibration active before it, whether it was stored and is now
    active, and the message (the fit's, and a note on missing prerequisites)."""

    record: dict
    measured: FrameMeasurement
    through: dict[str, str]
    previous: dict | None
    stored: bool
    active: bool
    message: str
    prerequisites: str = ''     # the results it was measured through that are nominal


def rig(repo, cell, kinematics: str, model=None):
    """The cell's rig through ``kinematics`` with the active TCP and hand-eye, read fresh;
    Refusal INVALID_INPUT naming the choices."""
    try:
        return rig_of(repo, cell, kinematics, model)
    except (KeyError, ValueError) as e:
        raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
            f'kinematics {kinematics!r}: {str(e).strip(chr(39))}; use latest, nominal or a '
            'stored kinematic calibration id'))) from None


def calibrate(repo, cell, request: Request, *, stamp_ns: int, robot=None, camera=None,
              model=None, frames_store=None, lock=contextlib.nullcontext(),
              cancelled: Cancelled = never, progress: Callable[[str], None] | None = None,
              on_view=None) -> Calibrated | Failure:
    """Measure (core.user_frame.procedure), record, store and activate ``request`` in ``repo``
    (the cell's repository; ``frames_store``: its user_frames, if the caller holds one open,
    used under ``lock``). A Failure with its cause when refused (nothing stored)."""
    frames_store = repo.user_frames if frames_store is None else frames_store
    unknown = landmark_frames.method_problem(request.method)
    if unknown is not None:
        return unknown
    try:
        measured, through = _measure(repo, cell, request, robot, camera, model, frames_store,
                                     lock, cancelled, progress, on_view)
    except Refusal as e:
        return e.failure
    if not measured:
        return measured
    record = UserFrameRecord.from_fit(
        measured.fit, measured.surface, measured.names, measured.p_user, measured.p_base,
        request.frames, stamp_ns, through.get('kinematics', ''), through.get('hand_eye', ''),
        through.get('tcp', ''), measured_through=through).to_dict()
    missing = missing_prerequisites('the user frame is', through)
    message = '; '.join(m for m in (measured.fit.message or 'calibrated', missing) if m)
    if not request.store:
        return Calibrated(record, measured, through, None, False, False, message, missing)
    try:
        with lock:
            previous = frames_store.active()
            active = bool(frames_store.save_and_activate(record))
    except OSError as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the calibration: {e}; '
                       'check data_dir (or --data-dir / --db)')
    return Calibrated(record, measured, through, previous, True, active, message, missing)


def _measure(repo, cell, request: Request, robot, camera, model, frames_store, lock,
             cancelled, progress, on_view) -> tuple[FrameMeasurement | Failure, dict]:
    """The measurement of ``request`` and what it was measured through (kind -> id)."""
    method = request.method or 'rigid'
    if method in landmark_frames.LANDMARK_METHODS:
        from cobot_calib_ros.core.landmarks import views
        problem = views.setup_problem(cell)
        if problem is not None:
            raise Refusal(Failure(problem.code, f'{method}: {problem.message}'))
        with lock:
            guess = _active_frame(frames_store)
        chosen = rig(repo, cell, request.kinematics, model)
        through = {'kinematics': chosen.active.kinematics_label,
                   'hand_eye': chosen.active.hand_eye_label,
                   'intrinsics': chosen.active.label('intrinsics')}
        return procedure.landmark_frame(
            method, cell, robot, camera, guess=guess, plan_chain=chosen.nominal_chain('camera'),
            chain=chosen.chain('camera'), gate=request.gate,
            capture_duration=request.capture_duration, cancelled=cancelled,
            on_view=on_view), through
    names = list(request.names)
    given = [len(p) for p in (request.p_user, request.p_base) if p is not None]
    if any(given):
        if names and len(names) != len(request.p_user):
            raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
                f'{len(names)} point names for {len(request.p_user)} points; give one name '
                'per point or none')))
        names = names or [f'P{i + 1}' for i in range(len(request.p_user))]
        if request.p_base is not None:
            return procedure.fit_points(method, names, request.p_user, request.p_base,
                                        request.gate), {}
    if not names:
        raise Refusal(Failure(ErrorCode.TOO_FEW_POINTS, (
            'no points: give points_user + points_base, or point_names of the cell to '
            'visit live')))
    chosen = rig(repo, cell, request.kinematics, model)
    through = {'kinematics': chosen.active.kinematics_label, 'tcp': chosen.active.tcp_label}
    if any(given):      # the joints of points of a file
        p_base = procedure.points_of_joints(chosen.chain('tcp'), request.joints)
        return procedure.fit_points(method, names, request.p_user, p_base,
                                    request.gate), through
    return procedure.touched_frame(
        method, cell, names, chosen.chain('tcp'), robot, joints=request.joints,
        gate=request.gate, capture_duration=request.capture_duration, cancelled=cancelled,
        progress=progress), through


def _active_frame(frames_store) -> np.ndarray:
    """Where the table is, to plan views by: the active user-frame calibration's."""
    record = frames_store.active()
    if record is None or record['result'].get('T_base_user') is None:
        raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
            'landmark methods plan their views by the active user frame and there is '
            'none: calibrate once with points first (a few millimetres off is fine)')))
    return np.array(record['result']['T_base_user'], dtype=float)


ACTIVATE, RETIRE = 'activate', 'retire'


def choose(frames_store, action: str, calibration_id: str,
           lock=contextlib.nullcontext()) -> str | Failure:
    """Apply ``action`` (ACTIVATE: ``calibration_id`` active, '' = back to the default, the
    newest non-retired; RETIRE) to the user frames: what is active now, or a Failure."""
    retire, cid = action == RETIRE, calibration_id
    if retire and not cid:
        return Failure(ErrorCode.INVALID_INPUT, 'RETIRE needs a calibration_id; '
                       'list_calibrations shows the stored ones')
    try:
        with lock:
            activation = frames_store.retire(cid) if retire else frames_store.activate(cid)
            active = frames_store.active()
    except Refusal as e:                # another cell's (store.cells)
        return e.failure
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, f'calibration_id {cid!r}: {e}')
    except KeyError:
        return Failure(ErrorCode.NO_CALIBRATION, f'no calibration {cid!r}; list_calibrations '
                       'shows the stored ones')
    except OSError as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the choice: {e}; nothing '
                       'changed, check data_dir')
    if cid and activation is not None and not activation:     # failed its gate
        return Failure(ErrorCode.INVALID_INPUT, activation.reason)
    now = (f'{active["id"]} is active' if active else
           'no calibration is active: calibrate, or activate a retired one')
    done = f'retired {cid}' if retire else (f'activated {cid}' if cid else
                                           'back to the default (newest non-retired)')
    return f'{done}; {now}'
