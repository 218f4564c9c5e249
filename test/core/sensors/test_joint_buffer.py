"""Ring buffer and hold-window statistics of capture_joints."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.sensors.joint_buffer import (hold_statistics, JointRingBuffer, Rejection,
                                                       StampGaps, StampMarks)

NAMES = ['j1', 'j2', 'j3']


def test_malformed_messages_are_rejected_with_their_reason():
    buf = JointRingBuffer(NAMES, capacity=10)
    assert buf.add(0.0, NAMES, [0.1, 0.2, math.nan]) == Rejection.NON_FINITE
    assert buf.add(0.0, NAMES, [0.1, 0.2]) == Rejection.LENGTH_MISMATCH
    assert buf.add(0.0, ['j1', 'j2', 'jX'], [0.1, 0.2, 0.3]) == Rejection.UNKNOWN_JOINTS
    assert buf.add(0.0, NAMES, [0.1, 0.2, 0.3]) is None
    assert buf.count == 1
    assert buf.rejected == {Rejection.NON_FINITE: 1, Rejection.LENGTH_MISMATCH: 1,
                            Rejection.UNKNOWN_JOINTS: 1}


def test_reordered_names_are_stored_in_buffer_order_and_ring_wraps():
    buf = JointRingBuffer(None, capacity=3)
    buf.add(0.0, NAMES, [1.0, 2.0, 3.0])
    buf.add(1.0, ['j3', 'j1', 'j2'], [3.5, 1.5, 2.5])
    for t in (2.0, 3.0):
        buf.add(t, NAMES, [t, t, t])
    times, q = buf.window(0.0, 10.0)
    np.testing.assert_array_equal(times, [1.0, 2.0, 3.0])       # t=0 overwritten
    np.testing.assert_array_equal(q[0], [1.5, 2.5, 3.5])


def test_hold_statistics_mean_std_and_refusals():
    t = np.linspace(0.0, 1.0, 1000)
    q = np.tile([0.1, 0.2, 0.3], (1000, 1))
    q[::2, 0] += 1e-6
    q[1::2, 0] -= 1e-6
    ok = hold_statistics(t, q, 1.0, 1000.0, 0.5, 1e-4, NAMES)
    assert ok.ok and ok.count == 1000
    np.testing.assert_allclose(ok.mean, [0.1, 0.2, 0.3], atol=1e-15)
    assert ok.std[0] == pytest.approx(np.sqrt(1000 / 999) * 1e-6, rel=1e-9)  # ddof=1
    few = hold_statistics(t[:400], q[:400], 1.0, 1000.0, 0.5, 1e-4, NAMES)
    assert few.code == ErrorCode.NO_DATA and 'only 400 joint_states samples' in few.message
    moving = q.copy()
    moving[:, 1] += np.linspace(0.0, 0.01, 1000)
    refused = hold_statistics(t, moving, 1.0, 1000.0, 0.5, 1e-4, NAMES)
    assert refused.code == ErrorCode.MOVING and 'j2' in refused.message


def test_stamp_marks_count_the_messages_before_each_whole_second():
    marks = StampMarks()
    for stamp_sec in (10, 10, 10, 11, 11, 13):
        marks.add(stamp_sec)
    assert marks.count == 6
    assert marks.mark == (13, 5)            # five messages stamped before second 13


def test_stamp_marks_give_the_exact_loss_between_two_shared_seconds():
    stamps = [s + k / 4 for s in range(10, 14) for k in range(4)]     # 4 per second
    publisher, subscriber = StampMarks(), StampMarks()
    history = {'pub': {}, 'sub': {}}
    lost = {5, 8, 9, 14}            # 8 is the first of second 12: the mark moves to the next
    for i, stamp in enumerate(stamps):
        publisher.add(int(stamp))
        history['pub'][publisher.mark[0]] = publisher.mark[1]
        if i not in lost:
            subscriber.add(int(stamp))
            history['sub'][subscriber.mark[0]] = subscriber.mark[1]
    published = history['pub'][13] - history['pub'][11]
    received = history['sub'][13] - history['sub'][11]
    assert published - received == 3        # 5, 8, 9 lie in [11 s, 13 s); 14 after it


def test_stamp_gaps_count_missing_periods_and_the_largest_gap():
    gaps = StampGaps(rate_hz=1000.0)
    for stamp in (0.000, 0.001, 0.002, 0.0052, 0.0062, 0.0071):
        gaps.add(stamp)
    assert gaps.missing == 2                # 3.2 ms gap: two periods missing
    assert gaps.take_max_gap() == pytest.approx(0.0032)
    assert gaps.take_max_gap() == 0.0       # starts over
