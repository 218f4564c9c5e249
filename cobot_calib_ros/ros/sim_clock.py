"""A /clock publisher at a chosen rate of wall time, for nodes run with ``use_sim_time``.

Used where simulated time must run faster or slower than wall time on purpose (the sim-time
node tests, bench/bench_sim_time.py); a bag replay publishes its recorded /clock instead
(bags.player).
"""
from __future__ import annotations

import threading
import time

from rosgraph_msgs.msg import Clock

from cobot_calib_ros.ros.time import ns_to_stamp, s_to_ns

PERIOD = 0.002          # [s] of wall time between /clock messages
START_NS = s_to_ns(1_000.0)


class SimClock:
    """Publishes /clock from its own thread at ``rate`` x wall time (changeable), starting at
    START_NS; ``sim_ns`` is the last time published [ns]."""

    def __init__(self, node, rate: float = 1.0, period: float = PERIOD) -> None:
        self.rate, self.sim_ns, self._period = rate, START_NS, period
        self._pub = node.create_publisher(Clock, '/clock', 10)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(self._period):
            now = time.monotonic()
            self.sim_ns += s_to_ns((now - last) * self.rate)
            last = now
            self._pub.publish(Clock(clock=ns_to_stamp(self.sim_ns)))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
