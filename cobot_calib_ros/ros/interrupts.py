"""Ctrl-C in a client's ROS session: noted by a signal handler, raised where the client waits.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives: in a CLI
client that is almost always inside rclpy (an executor's wait set, a future's callbacks, an
ActionClient's goal bookkeeping). Interrupted there, rclpy can be left holding a handle or a
half-registered request, and the session's teardown then hangs (``teach`` once did not exit
within 90 s of a Ctrl-C). Inside ``deferred()`` a SIGINT only sets a flag; ``check()``, which
every client wait loop calls between two spins (ros.calls.spin_until), raises the
KeyboardInterrupt there, outside rclpy. The flag is taken by the raise, so a client that
catches it to cancel a goal can wait for the cancel's answer, and a second Ctrl-C ends that
wait too. Leaving ``deferred()`` (after the session's teardown) raises an interrupt that no
wait took.
"""
from __future__ import annotations

import contextlib
import signal
import sys
import threading

_pending = 0          # SIGINTs noted and not yet raised
_depth = 0            # nesting of deferred() on the main thread


def _note(*_) -> None:
    global _pending
    _pending += 1


def pending() -> bool:
    """A Ctrl-C came that no wait has raised yet."""
    return _pending > 0


def check() -> None:
    """Raise KeyboardInterrupt (and take the flag) if a Ctrl-C is pending; on the main thread
    only, where a KeyboardInterrupt belongs."""
    global _pending
    if _pending and threading.current_thread() is threading.main_thread():
        _pending = 0
        raise KeyboardInterrupt


@contextlib.contextmanager
def deferred():
    """SIGINT noted instead of raised while inside (nests; a no-op off the main thread).

    On the way out of the outermost one the previous handler comes back, and a Ctrl-C that
    no check() raised is raised then (unless another exception is on its way out)."""
    global _depth, _pending
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _depth == 0:
        previous = signal.signal(signal.SIGINT, _note)
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0:
            signal.signal(signal.SIGINT, previous or signal.default_int_handler)
            interrupted, _pending = _pending, 0
            if interrupted and sys.exc_info()[0] is None:
                raise KeyboardInterrupt
