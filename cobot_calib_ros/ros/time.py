"""Time on the ROS side: header stamps <-> int nanoseconds, from the node clock.

Every stamp and every capture window comes from the node's clock, so ``use_sim_time`` with a
``/clock`` publisher (bag replay) works; core code sees int nanoseconds or float seconds.
The one home of NS_PER_S and of every stamp <-> ns <-> s conversion (test/test_facts.py
keeps it so); importing it loads no rclpy (bag tools use it too).
"""
from __future__ import annotations

from collections.abc import Callable
import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from builtin_interfaces.msg import Time
    from rclpy.node import Node

NS_PER_S = 1_000_000_000


def stamp_to_ns(stamp: Time) -> int:
    """A builtin_interfaces Time (or anything with sec, nanosec) [ns]."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def header_ns(msg) -> int:
    """A stamped message's header stamp [ns]."""
    return stamp_to_ns(msg.header.stamp)


def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of ``ns``, as a stamp holds it."""
    return divmod(int(ns), NS_PER_S)


def ns_to_stamp(ns: int) -> Time:
    from builtin_interfaces.msg import Time
    sec, nanosec = split_ns(ns)
    return Time(sec=sec, nanosec=nanosec)


def s_to_ns(seconds: float) -> int:
    """A duration or time [s] as int nanoseconds (rounded)."""
    return round(seconds * NS_PER_S)


def ns_to_s(ns: int) -> float:
    return ns / NS_PER_S


def now_ns(node: Node) -> int:
    """The node clock (ROS time: /clock under use_sim_time, else the system clock) [ns]."""
    return node.get_clock().now().nanoseconds


def stamp_or_now_ns(node: Node, stamp: Time) -> int:
    """A message's header stamp [ns]; the node clock when the sender left it zero."""
    return stamp_to_ns(stamp) or now_ns(node)


def wait_past(condition: threading.Condition, newest: Callable[[], tuple[float, int]],
              t1: float, stall: float) -> bool:
    """With ``condition`` held: wait until a sample stamped at or after ``t1`` [s] has arrived
    (the window is over in ROS time, whatever its rate to wall time; True, also when one had
    arrived before the call), or nothing new arrived for ``stall`` [s] of wall time (False:
    the stream has stopped). ``newest()`` gives (the newest stamp [s], the number of samples
    received so far); the receiver notifies ``condition`` after each sample."""
    stamp, count = newest()
    while stamp < t1:
        condition.wait(timeout=stall)
        stamp, latest = newest()
        if latest == count:
            return False
        count = latest
    return True
