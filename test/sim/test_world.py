"""The simulated cell's geometry against hand-computed values."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import Marker
from cobot_calib_ros.sim.world import HeightField, ray_box_distance, TrueMarker, World


def test_ray_box_distance_hits_top_face_and_misses_beside():
    lo, hi = np.array([-0.025, -0.015, 0.0]), np.array([0.025, 0.015, 0.02])
    down = np.array([0.0, 0.0, -1.0])
    assert ray_box_distance(np.array([0.01, 0.0, 0.0212]), down, lo, hi) == pytest.approx(0.0012)
    assert ray_box_distance(np.array([0.03, 0.0, 0.0212]), down, lo, hi) == math.inf
    side = np.array([1.0, 0.0, 0.0])   # probing the -x side face from 1 mm away
    assert ray_box_distance(np.array([-0.026, 0.0, 0.01]), side, lo, hi) == pytest.approx(0.001)


def test_ray_box_distance_over_several_boxes_is_the_nearest_hit():
    lo = np.array([[-0.025, -0.015, 0.0], [-0.025, -0.015, 0.0], [0.1, 0.0, 0.0]])
    hi = np.array([[0.025, 0.015, 0.02], [0.025, 0.015, 0.01], [0.2, 0.1, 0.05]])
    down = np.array([0.0, 0.0, -1.0])
    assert ray_box_distance(np.array([0.01, 0.0, 0.0212]), down, lo, hi) == pytest.approx(0.0012)
    assert ray_box_distance(np.array([0.01, 0.0, 0.015]), down, lo, hi) == 0.0    # inside one
    assert ray_box_distance(np.array([0.05, 0.0, 0.0212]), down, lo, hi) == math.inf


def test_probe_gap_follows_marker_height_and_user_frame():
    field = HeightField(amplitude=0.0, tilt=(0.001, 0.0))      # 1 mm per metre along x
    marker = TrueMarker(Marker('P1', (0.2, 0.1), (0.05, 0.03, 0.02)), float(field(0.2, 0.1)),
                        5e-5)
    T_base_user = frames.from_xyz_rpy([0.5, -0.1, 0.03], [0.0, 0.0, 0.4])
    world = World(T_base_user, (marker,), field)
    assert marker.top_z == pytest.approx(0.0002 + 0.02 + 5e-5)
    T_user_tool = frames.make_transform(frames.rot_x(math.pi), [0.2, 0.1, 0.0215])
    gap = world.probe_gap(T_base_user @ T_user_tool)
    assert gap == pytest.approx(0.0215 - 0.02025, abs=1e-12)
