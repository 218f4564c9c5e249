"""The simulated cell's geometry and probe curve, against hand-computed values."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import (HeightField, Marker, ProbeCurve, ray_box_distance,
                                       World)
from cobot_calib_ros.core.sensors.probe import read_distance, ReadingStatus

CURVE = ProbeCurve((0.0002, 0.0012, 0.0022), (-1.6, -9.6, -17.6))


def test_ray_box_distance_hits_top_face_and_misses_beside():
    lo, hi = np.array([-0.025, -0.015, 0.0]), np.array([0.025, 0.015, 0.02])
    down = np.array([0.0, 0.0, -1.0])
    assert ray_box_distance(np.array([0.01, 0.0, 0.0212]), down, lo, hi) == pytest.approx(0.0012)
    assert ray_box_distance(np.array([0.03, 0.0, 0.0212]), down, lo, hi) == math.inf
    side = np.array([1.0, 0.0, 0.0])   # probing the -x side face from 1 mm away
    assert ray_box_distance(np.array([-0.026, 0.0, 0.01]), side, lo, hi) == pytest.approx(0.001)


def test_probe_gap_follows_marker_height_and_user_frame():
    field = HeightField(amplitude=0.0, tilt=(0.001, 0.0))      # 1 mm per metre along x
    marker = Marker('P1', (0.2, 0.1), (0.05, 0.03, 0.02), float(field(0.2, 0.1)), 5e-5)
    T_base_user = frames.from_xyz_rpy([0.5, -0.1, 0.03], [0.0, 0.0, 0.4])
    world = World(T_base_user, (marker,), field)
    assert marker.top_z == pytest.approx(0.0002 + 0.02 + 5e-5)
    T_user_tool = frames.make_transform(frames.rot_x(math.pi), [0.2, 0.1, 0.0215])
    gap = world.probe_gap(T_base_user @ T_user_tool)
    assert gap == pytest.approx(0.0215 - 0.02025, abs=1e-12)


def test_probe_curve_saturates_and_inverts():
    assert CURVE.to_voltage(0.0007) == pytest.approx(-5.6)
    assert CURVE.to_voltage(0.0) == pytest.approx(-1.6)       # saturated below range
    assert CURVE.to_voltage(0.01) == pytest.approx(-17.6)     # saturated above range
    assert CURVE.to_distance(-5.6) == pytest.approx(0.0007)


@pytest.mark.parametrize('voltage, status', [
    (-5.6, ReadingStatus.OK), (-1.6, ReadingStatus.BELOW_RANGE), (-1.0, ReadingStatus.BELOW_RANGE),
    (-17.6, ReadingStatus.ABOVE_RANGE), (-30.0, ReadingStatus.ABOVE_RANGE),
    (math.nan, ReadingStatus.INVALID), (math.inf, ReadingStatus.INVALID)])
def test_read_distance_range_check(voltage, status):
    reading = read_distance(CURVE, voltage, saturation_margin=2e-6)
    assert reading.status == status
    assert math.isnan(reading.distance) == (status != ReadingStatus.OK)
