"""Landmark user frames: which views to take, and the frame from what they saw. Pure; SI units.

A landmark method measures the user frame with the wrist camera (issue 11):
- ``landmark_single`` looks straight down at the cell's lowest-id fiducial from VIEW_DISTANCE
  (one marker, one view: the first paper's built-in method);
- ``landmark_multi`` looks at every fiducial from three views (above, tilted +-20 deg).

:func:`plan_views` gives the joints of each view, planned on a chain whose tool is the camera
(the hand-eye), around a guess of the user frame. Each view then yields T_base_optical (FK of
the joints captured there, on the model the frame is measured with) and the markers' poses in
the optical frame: :func:`observation` puts one in the base frame, and :func:`landmark_frame`
fits the frame (core.user_frame.landmarks). :func:`measure_frame` is the whole procedure over
the robot and camera ports (core.robot_port): ROS's RobotCalls and LandmarkWatch, or the
simulation's DirectRobot and DirectCamera in-process.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.robot_port import (CameraPort, Capture, Cancelled, check_cancel,
                                             LandmarkImage, never, PortError, RobotPort, Stopped)
from cobot_calib_ros.core.user_frame import landmarks as landmark_frames

Array = NDArray[np.float64]
VIEW_DISTANCE = 0.35     # [m] camera above a marker's centre
VIEW_TILTS = (0.0, np.radians(20.0), -np.radians(20.0))   # landmark_multi: views per marker
VIEW_ROLLS = (0.0, np.pi / 2, -np.pi / 2, np.pi)          # about the view axis, tried in turn
LANDMARK_IMAGES = 3      # images after a capture looked at before a marker counts as unseen
LANDMARK_TIMEOUT = 5.0   # [s] of wall time for an image stamped after a capture
LANDMARK_MAX_RMS = 5e-3  # [m] plausibility of landmark_multi: camera poses are mm-class (the
                         # nominal hand-eye alone is a few mm off at VIEW_DISTANCE)


def target_ids(method: str, cell) -> list[int]:
    """The fiducial ids a landmark method looks at."""
    ids = sorted(cell.landmarks.markers)
    return ids[:1] if method == landmark_frames.LANDMARK_SINGLE else ids


def plan_views(method: str, cell, plan_chain: kinematics.Chain, T_base_user_guess: Array,
               q_start: Array) -> list[tuple[int, Array]]:
    """(marker id, joints [rad]) of every reachable view, in visiting order. ``plan_chain``'s
    tool is the camera's optical frame. A marker with no reachable view has no entry."""
    tilts = VIEW_TILTS[:1] if method == landmark_frames.LANDMARK_SINGLE else VIEW_TILTS
    home = np.asarray(cell.home, dtype=float)
    views, q_prev = [], np.asarray(q_start, dtype=float)
    for marker_id in target_ids(method, cell):
        T_base_marker = T_base_user_guess @ cell.landmarks.T_user_marker(marker_id)
        for tilt in tilts:
            q = _view(plan_chain, T_base_marker, tilt, q_prev, home)
            if q is not None:
                views.append((marker_id, q))
                q_prev = q
    return views


def _view(chain, T_base_marker: Array, tilt: float, q_seed: Array, home: Array) -> Array | None:
    """Joints putting the camera VIEW_DISTANCE from the marker centre, looking at it, tilted
    by ``tilt`` about the marker's x axis; None if no roll of VIEW_ROLLS is reachable."""
    for roll in VIEW_ROLLS:
        T_marker_optical = (frames.make_transform(frames.rot_x(tilt), np.zeros(3))
                            @ frames.make_transform(frames.rot_x(np.pi), [0.0, 0.0, VIEW_DISTANCE])
                            @ frames.make_transform(frames.rot_z(roll), np.zeros(3)))
        ik = kinematics.solve_ik_with_restarts(chain, T_base_marker @ T_marker_optical,
                                               q_seed, home)
        if ik:
            return np.asarray(ik.q, dtype=float)
    return None


def observation(marker_id: int, T_base_optical: Array, T_optical_marker: Array,
                covariance_optical: Array) -> landmark_frames.Observation:
    """One marker seen in one view, in the base frame: (id, T_base_marker, 6x6 covariance in
    base axes; the camera pose's own uncertainty is not in it)."""
    B = np.kron(np.eye(2), np.asarray(T_base_optical)[:3, :3])
    C = np.asarray(covariance_optical, dtype=float).reshape(6, 6)
    return int(marker_id), T_base_optical @ T_optical_marker, B @ C @ B.T


def landmark_frame(method: str, cell, observations: Sequence[landmark_frames.Observation], *,
                   max_rms_error: float, max_scale_error: float) -> landmark_frames.LandmarkFit:
    """The method's frame from the observations (ids outside the method's targets ignored);
    falsy with CAPTURE_FAILED naming the targets never seen, or with the fit's failure."""
    targets = target_ids(method, cell)
    usable = [o for o in observations if o[0] in targets]
    unseen = sorted(set(targets) - {o[0] for o in usable})
    if unseen:
        return landmark_frames.LandmarkFit.failed(method, Failure(ErrorCode.CAPTURE_FAILED, (
            f'{method}: landmark(s) {unseen} never seen (or no view of them was reachable); '
            'check the camera, the landmarks topic and the user frame the views are planned '
            'by')))
    T_um = {i: cell.landmarks.T_user_marker(i) for i in sorted(cell.landmarks.markers)}
    if method == landmark_frames.LANDMARK_SINGLE:
        i, T, C = usable[-1]
        return landmark_frames.frame_from_single(T, T_um[i], covariance=C, marker_id=i)
    return landmark_frames.frame_from_landmarks(
        usable, T_um, max_rms_error=max(max_rms_error, LANDMARK_MAX_RMS),
        max_scale_error=max_scale_error)


def setup_problem(cell) -> Failure | None:
    """None when the cell has a camera and landmarks, else an INVALID_INPUT Failure saying
    what to add to the cell file."""
    if cell.camera is None or cell.landmarks is None or not cell.landmarks.markers:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'cell {cell.name!r} has no wrist camera or no landmarks; add camera: and '
                       'landmarks: markers: to the cell file')
    return None


ViewMark = Callable[[int, Capture, int], None]   # marker id, the view's capture, t [ns]


def measure_frame(method: str, cell, robot: RobotPort, camera: CameraPort, *,
                  T_base_user_guess: Array, plan_chain: kinematics.Chain,
                  chain: kinematics.Chain, capture_duration: float, max_rms_error: float,
                  max_scale_error: float, cancelled: Cancelled = never,
                  on_view: ViewMark | None = None) -> landmark_frames.LandmarkFit:
    """A landmark method's frame, measured: the views of :func:`plan_views` (on ``plan_chain``,
    its tool the hand-eye the views are planned with, from the cell's home), each visited
    (move, capture the joints for ``capture_duration`` [s]), then the first image stamped after
    the capture that shows the view's marker (else the last of LANDMARK_IMAGES) gives every
    marker's T_optical_marker; T_base_optical = FK of the captured joints on ``chain`` (its
    tool: the hand-eye the frame is measured with). ``on_view(marker id, capture, t)`` once
    per view, before the images after ``t`` are looked at (ROS publishes its capture mark).

    Falsy with INVALID_INPUT without camera or landmarks, CAPTURE_FAILED when a view could not
    be taken or a target was never seen; else :func:`landmark_frame`'s fit (falsy when refused).
    Raises core.robot_port.Stopped when ``cancelled()`` between views."""
    problem = setup_problem(cell)
    if problem is not None:
        return landmark_frames.LandmarkFit.failed(
            method, Failure(problem.code, f'{method}: {problem.message}'))
    observations = []
    for marker_id, q in plan_views(method, cell, plan_chain, T_base_user_guess, cell.home):
        check_cancel(cancelled, f'the view of landmark {marker_id}')
        try:
            capture, image = _take_view(robot, camera, marker_id, q, capture_duration, on_view)
        except Stopped:
            raise
        except PortError as e:
            return landmark_frames.LandmarkFit.failed(method, Failure(
                ErrorCode.CAPTURE_FAILED, f'{method}: view of landmark {marker_id}: {e}'))
        T_base_optical = kinematics.fk(chain, capture.q)
        observations += [observation(s.id, T_base_optical, s.T_optical_target, s.covariance)
                         for s in image.sightings if s.kind == 'marker']
    return landmark_frame(method, cell, observations, max_rms_error=max_rms_error,
                          max_scale_error=max_scale_error)


def _take_view(robot: RobotPort, camera: CameraPort, marker_id: int, q: Array,
               duration: float, on_view: ViewMark | None) -> tuple[Capture, LandmarkImage]:
    """Move to ``q``, capture, and take the landmarks of an image stamped after the capture."""
    robot.move_joints(q)
    capture = robot.capture(duration)
    t_ns = camera.now_ns()
    if on_view is not None:
        on_view(marker_id, capture, t_ns)
    image = camera.landmarks_after(t_ns, lambda im: im.find('marker', marker_id) is not None,
                                   LANDMARK_IMAGES, LANDMARK_TIMEOUT)
    return capture, image
