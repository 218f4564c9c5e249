"""joint_state_monitor's hold on a thinned stream, without timing: the monitor's thread woken
late (a loaded machine) finds the samples of the windows after the first already buffered.
That is no stopped stream: the hold goes on by windows until it has the samples it needs (a
CI run refused such a hold after 2 windows, 80 of 100 samples)."""
from types import SimpleNamespace
import threading

import numpy as np

from cobot_calib_ros.core.sensors.joint_buffer import JointRingBuffer, samples_needed
from cobot_calib_ros.nodes.joint_state_monitor import JointStateMonitor

RATE_HZ, THINNED_HZ, DURATION = 1000.0, 200.0, 0.2      # [Hz], [Hz], [s]


def monitor_with(stamps) -> SimpleNamespace:
    lock = threading.Lock()
    buffer = JointRingBuffer(['j1', 'j2'], 10_000)
    for t in stamps:
        assert buffer.add(float(t), ['j1', 'j2'], [0.1, -0.2]) is None
    return SimpleNamespace(_lock=lock, _new_sample=threading.Condition(lock), _buffer=buffer)


def test_samples_already_there_for_later_windows_let_the_hold_go_on():
    t0 = 100.0
    # all of them buffered, mid-period (none on a window's edge)
    stamps = t0 + (np.arange(200) + 0.5) / THINNED_HZ
    needed = samples_needed(DURATION, RATE_HZ, 0.5)
    times, positions, names, windows = JointStateMonitor._hold(
        monitor_with(stamps), t0, DURATION, needed, streaming=True)
    assert needed == 100 and windows == 3 and len(times) == 120
    assert names == ['j1', 'j2'] and positions.shape == (120, 2)


def test_without_a_stream_the_hold_is_one_window():
    t0 = 100.0
    stamps = t0 + (np.arange(200) + 0.5) / THINNED_HZ      # mid-period: none on an edge
    times, _, _, windows = JointStateMonitor._hold(monitor_with(stamps), t0, DURATION, 100,
                                                   streaming=False)
    assert windows == 1 and len(times) == 40
