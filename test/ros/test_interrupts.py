"""ros.interrupts: a Ctrl-C in a client's ROS session reaches the client's wait, wherever the
signal arrives (issue 16.4: `teach` hung after a Ctrl-C that rclpy swallowed)."""
import gc
import os
import signal

import pytest

from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.cli.common import ros_node
from cobot_calib_ros.ros import interrupts


class _CtrlCWhenCollected:
    """Sends this process a SIGINT from inside __del__, as a Ctrl-C that arrives while the
    garbage collector closes one of rclpy's generators (executors.py: _wait_for_ready_callbacks,
    the frame teach was stuck after): Python raises KeyboardInterrupt there, prints "Exception
    ignored in" and goes on as if no Ctrl-C had come."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)


def test_a_ctrl_c_during_garbage_collection_ends_the_next_wait():
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with ros_node('test_interrupts') as node:
            _CtrlCWhenCollected()
            gc.collect()
            # on 5252a67 the interrupt is lost and this waits its 30 s, then returns False
            spin_until(node, lambda: False, 30.0)
    assert signal.getsignal(signal.SIGINT) is before     # restored
    assert not interrupts.pending()


def test_a_ctrl_c_that_no_wait_took_is_raised_after_the_teardown():
    torn_down = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts.deferred():
            try:
                os.kill(os.getpid(), signal.SIGINT)      # noted, not raised here
                assert interrupts.pending()
            finally:
                torn_down.append(True)
    assert torn_down and not interrupts.pending()


def test_a_client_can_catch_the_interrupt_and_wait_again():
    """As a goal is canceled after Ctrl-C: the first wait raises, the next one (for the cancel's
    answer) runs, and a second Ctrl-C ends that one too."""
    with interrupts.deferred():
        os.kill(os.getpid(), signal.SIGINT)
        with pytest.raises(KeyboardInterrupt):
            interrupts.check()
        interrupts.check()                               # taken: no second raise
        os.kill(os.getpid(), signal.SIGINT)
        with pytest.raises(KeyboardInterrupt):
            interrupts.check()
