"""ros.time: waiting for a window's end in ROS time.

The condition is scripted: each wait delivers the next sample of the script (None: nothing
arrives within the wait), so the test shows which event ended the wait without timing it
(bench/bench_waits.py times the stall on a real condition)."""
import threading

from cobot_calib_ros.ros.time import wait_past


class ScriptedArrivals:
    """A condition whose wait(timeout) delivers the next stamp of ``arrivals`` (None: none)."""

    def __init__(self, arrivals) -> None:
        self.arrivals, self.timeouts = list(arrivals), []
        self.stamp, self.count = 0.0, 0

    def wait(self, timeout=None) -> bool:
        self.timeouts.append(timeout)
        arrival = self.arrivals.pop(0)
        if arrival is not None:
            self.stamp, self.count = arrival, self.count + 1
        return arrival is not None

    def newest(self) -> tuple[float, int]:
        return self.stamp, self.count


def test_wait_past_ends_on_the_first_sample_stamped_at_or_after_t1():
    stream = ScriptedArrivals([0.5, 1.0, 1.5, 2.0])
    assert wait_past(stream, stream.newest, 1.5, stall=1.0) is True
    assert stream.stamp == 1.5 and stream.arrivals == [2.0]
    assert stream.timeouts == [1.0, 1.0, 1.0]       # each wait bounded by the stall


def test_wait_past_gives_up_after_one_stall_not_after_a_fixed_time():
    """A slow clock (samples keep coming, stamps short of t1) keeps it waiting; one wait
    with nothing new ends it (the caller then finds no data)."""
    stream = ScriptedArrivals([0.5, 1.0, 1.5, 2.0, None, 9.5])
    assert wait_past(stream, stream.newest, 9.0, stall=0.3) is False
    assert stream.stamp == 2.0 and stream.arrivals == [9.5]
    assert stream.timeouts == [0.3] * 5


def test_wait_past_returns_at_once_when_the_window_is_already_over():
    """Not a stopped stream (a waiter woken late finds the next window's samples there)."""
    stream = ScriptedArrivals([3.0])
    stream.wait()
    stream.timeouts.clear()
    assert wait_past(stream, stream.newest, 2.0, stall=1.0) is True
    assert stream.timeouts == []


def test_wait_past_wakes_on_a_notify_from_the_receiver_thread():
    """With a real condition: a receiver that notifies after each sample ends the wait with
    the condition held, on the sample stamped t1 (the stall is far longer than the test).
    The receiver delivers one sample per look at newest(), so none overtakes the check."""
    condition, state = threading.Condition(), {'stamp': 0.0, 'count': 0}
    looked = threading.Semaphore(0)

    def feed(stamps):
        for stamp in stamps:
            looked.acquire()
            with condition:
                state['stamp'], state['count'] = stamp, state['count'] + 1
                condition.notify_all()

    def newest() -> tuple[float, int]:
        looked.release()
        return state['stamp'], state['count']
    feeder = threading.Thread(target=feed, args=([0.5, 1.0, 1.5, 2.0],))
    with condition:
        feeder.start()
        wait_past(condition, newest, 1.5, stall=600.0)
        assert state['stamp'] == 1.5 and state['count'] == 3
    feeder.join(timeout=60.0)
    assert state['stamp'] == 2.0
