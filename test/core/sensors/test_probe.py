"""The probe's calibration table and range checks, against hand-computed values."""
import math

import pytest

from cobot_calib_ros.core.sensors.probe import ProbeCurve, Reading, read_distance, ReadingStatus

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


OK, BELOW, ABOVE, INVALID = (ReadingStatus.OK, ReadingStatus.BELOW_RANGE,
                             ReadingStatus.ABOVE_RANGE, ReadingStatus.INVALID)


def _window(*readings):
    """(stamp [ns], distance [m], status) samples 1 ms apart."""
    return [(k * 1_000_000, d, s) for k, (d, s) in enumerate(readings)]


def test_average_is_the_mean_and_sample_std_of_the_in_range_readings():
    from cobot_calib_ros.core.errors import ErrorCode
    from cobot_calib_ros.core.sensors.probe import average
    result = average(_window((1.0e-3, OK), (1.2e-3, OK), (math.nan, ABOVE), (1.4e-3, OK)), 0.2)
    assert result and result.code == ErrorCode.SUCCESS
    assert result.distance == pytest.approx(1.2e-3)
    assert result.std == pytest.approx(0.2e-3)                # n - 1: sqrt(0.08 / 2) um
    assert (result.sample_count, result.rejected_count) == (3, 1)
    assert result.reading() == Reading(pytest.approx(1.2e-3), OK)


def test_average_needs_a_majority_in_range_and_names_the_side():
    from cobot_calib_ros.core.errors import ErrorCode
    from cobot_calib_ros.core.sensors.probe import average
    half = average(_window((1.0e-3, OK), (math.nan, BELOW)), 0.2)   # 1 of 2: not a majority
    assert not half and half.code == ErrorCode.OUT_OF_RANGE and half.status == BELOW
    assert 'closer than the probe range' in half.message
    reading = half.reading()
    assert reading.status == BELOW and math.isnan(reading.distance)
    above = average(_window((math.nan, ABOVE), (math.nan, ABOVE), (math.nan, BELOW)), 0.2)
    assert above.status == ABOVE and 'beyond the probe range' in above.message


def test_mostly_invalid_readings_are_no_reading_not_out_of_range():
    """The node's rule (the in-process robot used to call this 'above range' and step the
    probe away): a probe signal that is not a number gives no reading at all."""
    from cobot_calib_ros.core.errors import ErrorCode
    from cobot_calib_ros.core.sensors.probe import average
    result = average(_window((math.nan, INVALID), (math.nan, INVALID), (1e-3, OK)), 0.2)
    assert result.code == ErrorCode.OUT_OF_RANGE and result.status == INVALID
    assert result.reading() is None and 'not a number' in result.message


def test_an_empty_window_is_no_data_and_the_window_keeps_both_ends():
    from cobot_calib_ros.core.errors import ErrorCode
    from cobot_calib_ros.core.sensors.probe import average, average_window
    empty = average([], 0.25)
    assert empty.code == ErrorCode.NO_DATA and '0.250 s' in empty.message
    assert empty.reading() is None
    samples = _window(*[(1e-3, OK)] * 10)                        # stamps 0..9 ms
    assert [s[0] for s in average_window(samples, 2_000_000, 0.003)] == [
        2_000_000, 3_000_000, 4_000_000, 5_000_000]
