"""Ring buffer and hold-window statistics of capture_joints."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core.sensors.joint_buffer import hold_statistics, JointRingBuffer, Rejection

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
    assert few.reason == 'no_data' and 'only 400 joint_states samples' in few.message
    moving = q.copy()
    moving[:, 1] += np.linspace(0.0, 0.01, 1000)
    refused = hold_statistics(t, moving, 1.0, 1000.0, 0.5, 1e-4, NAMES)
    assert refused.reason == 'moving' and 'j2' in refused.message
