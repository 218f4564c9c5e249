"""The probe's calibration table and range checks, against hand-computed values."""
import math

import pytest

from cobot_calib_ros.core.sensors.probe import ProbeCurve, read_distance, ReadingStatus

CURVE = ProbeCurve((0.0002, 0.0012, 0.0022), (-1.6, -9.6, -17.6))


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
