"""ros.time: waiting for a window's end in ROS time."""
import threading
import time

from cobot_calib_ros.ros.time import wait_past


def test_wait_past_ends_on_a_late_stamp_or_a_stalled_stream():
    """ros.time.wait_past: done when a sample stamped past t1 arrives, and gives up after
    `stall` s with nothing new (not after a fixed time: a slow clock keeps it waiting)."""
    condition, state = threading.Condition(), {'stamp': 0.0, 'count': 0}

    def feed(stamps):
        for stamp in stamps:
            time.sleep(0.05)
            with condition:
                state['stamp'], state['count'] = stamp, state['count'] + 1
                condition.notify_all()
    newest = lambda: (state['stamp'], state['count'])  # noqa: E731
    feeder = threading.Thread(target=feed, args=([0.5, 1.0, 1.5, 2.0],))
    started = time.monotonic()
    with condition:
        feeder.start()
        wait_past(condition, newest, 1.5, stall=1.0)
        assert state['stamp'] == 1.5 and time.monotonic() - started < 0.5
    feeder.join()
    started = time.monotonic()
    with condition:
        wait_past(condition, newest, 9.0, stall=0.3)    # nothing more arrives
    assert 0.25 < time.monotonic() - started < 1.0 and state['stamp'] == 2.0
