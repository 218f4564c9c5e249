"""Readings stamped when taken: a starved publisher's late burst still fills its window."""
import pytest

from cobot_calib_ros.core.sensors.probe import average, average_window, ReadingStatus
from cobot_calib_ros.core.sensors.sample_clock import SampleClock

MS = 1_000_000          # [ns]


def test_on_time_one_sample_per_period():
    clock = SampleClock(5 * MS, 1000 * MS)
    assert clock.due(100 * MS) == [100 * MS]
    assert clock.due(103 * MS) == []
    assert clock.due(105 * MS) == [105 * MS]
    assert clock.due(111 * MS) == [110 * MS]
    assert clock.due(115 * MS) == [115 * MS]          # sample times do not drift with ticks


def test_a_stall_is_caught_up_with_the_sample_times_it_missed():
    clock = SampleClock(5 * MS, 1000 * MS)
    clock.due(0)
    burst = clock.due(150 * MS)                        # the publisher slept 150 ms
    assert burst == [k * 5 * MS for k in range(1, 31)]
    assert clock.dropped == 0


def test_a_stall_longer_than_the_backlog_keeps_the_newest_and_counts_the_rest():
    clock = SampleClock(5 * MS, 100 * MS)
    clock.due(0)
    burst = clock.due(300 * MS)
    assert burst[0] == 200 * MS and burst[-1] == 300 * MS and len(burst) == 21
    assert clock.dropped == 39                         # 5 ... 195 ms
    assert clock.due(305 * MS) == [305 * MS]


def test_a_clock_that_went_back_starts_over():
    clock = SampleClock(5 * MS, 1000 * MS)
    clock.due(500 * MS)
    assert clock.due(20 * MS) == [20 * MS]             # a replay restarted its /clock
    assert clock.dropped == 0


def test_bad_periods_are_refused():
    with pytest.raises(ValueError, match='period'):
        SampleClock(0, 100)
    with pytest.raises(ValueError, match='backlog'):
        SampleClock(10, 5)


def test_an_average_inside_a_stall_gets_every_reading_the_probe_took():
    """issue 31: 'no probe readings in 0.080 s' when the publisher starved through the window.
    Readings stamped at publish time leave the stall empty; sample-clock stamps fill it."""
    clock = SampleClock(5 * MS, 1000 * MS)             # 200 Hz
    distance = {0: 1.0e-3, 1: 1.2e-3}                  # before the stall / during and after it
    readings = [(t, distance[0], ReadingStatus.OK) for t in clock.due(0)]
    readings += [(t, distance[0], ReadingStatus.OK) for t in clock.due(20 * MS)]
    readings += [(t, distance[1] if t > 20 * MS else distance[0], ReadingStatus.OK)
                 for t in clock.due(200 * MS)]         # one late burst after 180 ms
    window = average_window(readings, 60 * MS, 0.080)
    assert [t for t, _, _ in window] == [k * 5 * MS for k in range(12, 29)]
    result = average(window, 0.080)
    assert result and result.sample_count == 17
    assert result.distance == pytest.approx(1.2e-3, abs=1e-15)
    publish_time_stamps = [0, 20 * MS, 200 * MS]       # what stamping at publish time gave
    assert not average_window([(t, 1.0, ReadingStatus.OK) for t in publish_time_stamps],
                              60 * MS, 0.080)
