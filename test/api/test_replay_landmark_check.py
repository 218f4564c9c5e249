"""api.replay_landmark_check.fit_frame on view marks and landmarks messages built from a known
frame: the frame comes back, and a refused fit is a CheckError with the fit's message (on
5252a67 a falsy LandmarkFit had no ``message``: AttributeError)."""
from __future__ import annotations

import numpy as np
import pytest
from cobot_calib_msgs.msg import CaptureMark, Landmark, Landmarks

from cobot_calib_ros import paths
from cobot_calib_ros.api import replay_landmark_check as check
from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.ros import convert

CELL = 'sawyer_close'
T_BASE_USER = frames.from_xyz_rpy([0.6, -0.1, 0.05], [0.0, 0.0, 0.2])


def session(shift: dict[int, float]) -> tuple[list, list]:
    """One view mark at home and its landmarks message showing every marker of the cell at
    T_BASE_USER (marker i moved ``shift[i]`` [m] along the optical x axis)."""
    cell = load_cell(paths.cell_file(CELL))
    model = kinematics.model_for(cell)
    q = np.asarray(cell.home, dtype=float)
    T_base_optical = kinematics.fk(
        model.chain(tool=np.asarray(cell.camera.T_flange_optical, dtype=float)), q)
    msg = Landmarks()
    for i in sorted(cell.landmarks.markers):
        T = frames.invert(T_base_optical) @ T_BASE_USER @ cell.landmarks.T_user_marker(i)
        T[0, 3] += shift.get(i, 0.0)
        msg.landmarks.append(Landmark(id=i, kind=Landmark.KIND_MARKER))
        msg.landmarks[-1].pose.pose = convert.matrix_to_pose(T)
        msg.landmarks[-1].pose.covariance = list(np.eye(6).ravel() * 1e-8)
    mark = CaptureMark(target=f'landmark_{sorted(cell.landmarks.markers)[0]}',
                       joint_names=list(model.joint_names), position_rad=q.tolist())
    return [mark], [msg]


def test_the_frame_of_consistent_views_comes_back() -> None:
    fit = check.fit_frame(*session({}), cell_name=CELL)
    assert fit and fit.code == 0
    translation, rotation = frames.transform_error(fit.fit.T_base_user, T_BASE_USER)
    assert translation < 1e-9 and rotation < 1e-9


def test_a_refused_fit_is_a_check_error_with_its_message() -> None:
    cell = load_cell(paths.cell_file(CELL))
    first = sorted(cell.landmarks.markers)[0]
    with pytest.raises(check.CheckError, match='the landmark fit failed: .*residual'):
        check.fit_frame(*session({first: 0.05}), cell_name=CELL)    # one marker 5 cm off
