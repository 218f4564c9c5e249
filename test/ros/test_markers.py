"""ros.markers: the live view's MarkerArrays from a calibration message, checked on fixed data."""
from cobot_calib_msgs.msg import PointResidual, UserFrameCalibration
import numpy as np
import pytest
from visualization_msgs.msg import Marker

from cobot_calib_ros.ros import markers


def _calibration() -> UserFrameCalibration:
    msg = UserFrameCalibration(id='x')
    msg.transform.header.frame_id = 'base'
    T = np.eye(4)
    T[:3, 3] = [0.5, -0.1, 0.02]
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]       # user x along base y
    msg.matrix = T.ravel().tolist()
    for name, p, r, outlier in (('P1', (0.5, 0.0, 0.02), (1e-4, 0, 0), False),
                                ('P2', (0.6, 0.1, 0.02), (0, 0, -1e-3), True)):
        res = PointResidual(name=name, residual_norm=float(np.linalg.norm(r)), outlier=outlier)
        res.point_base.x, res.point_base.y, res.point_base.z = p
        res.residual.x, res.residual.y, res.residual.z = r
        msg.residuals.append(res)
    return msg


def test_user_frame_layers_clear_only_their_own_namespaces_first():
    array = markers.user_frame_markers(_calibration(), gate=1e-3).markers
    clears = [m for m in array if m.action == Marker.DELETEALL]
    assert [m.ns for m in clears] == list(markers.USER_FRAME_LAYERS) == [m.ns for m in array[:4]]
    assert all(m.header.frame_id == 'base' for m in array[4:])


def test_points_residual_arrows_and_axes_are_where_the_calibration_says():
    array = [m for m in markers.user_frame_markers(_calibration(), gate=1e-3).markers
             if m.action == Marker.ADD]
    points = next(m for m in array if m.ns == 'user_frame/points')
    assert points.type == Marker.SPHERE_LIST
    assert [(p.x, p.y, p.z) for p in points.points] == [(0.5, 0.0, 0.02), (0.6, 0.1, 0.02)]
    assert (points.colors[1].r, points.colors[1].g) == (1.0, 0.2)          # the outlier: red
    arrows = [m for m in array if m.ns == 'user_frame/residuals']
    tip = arrows[0].points[1]
    assert (tip.x, tip.y, tip.z) == pytest.approx((0.5 + 100 * 1e-4, 0.0, 0.02))   # 100x
    assert arrows[1].color.r == pytest.approx(1.0) and arrows[1].color.g == pytest.approx(0.2)
    assert arrows[0].color.r == pytest.approx(0.28) and arrows[0].color.g == pytest.approx(0.74)
    x_axis = next(m for m in array if m.ns == 'user_frame/frame')
    start, end = x_axis.points
    assert (start.x, start.y, end.x, end.y) == pytest.approx((0.5, -0.1, 0.5, 0.0))  # +y base
    labels = [m.text for m in array if m.ns == 'user_frame/labels']
    assert labels == ['P1 0.100 mm', 'P2 1.000 mm']


def test_sphere_layers_and_an_empty_collection():
    array = markers.sphere_markers('base', None, np.zeros((3, 3)), np.ones((4, 3))).markers
    kinds = {m.ns: len(m.points) for m in array if m.action == Marker.ADD}
    assert kinds == {'kinematics/spheres': 3, 'kinematics/poses': 4}
    empty = markers.sphere_markers('base', None, np.zeros((3, 3)), np.empty((0, 3))).markers
    assert [m.ns for m in empty if m.action == Marker.ADD] == ['kinematics/spheres']
