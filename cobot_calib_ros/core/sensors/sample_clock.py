"""The stamps of a sensor that samples on its own clock at a fixed period.

A probe's ADC keeps sampling while the host is busy; its driver delivers the buffered readings
late, each stamped with the time it was taken. Stamping at publish time instead leaves a gap
wherever the publisher was starved, and a short averaging window inside that gap finds no
readings at all (issue 31: "no probe readings in 0.080 s" at load ~12).
"""
from __future__ import annotations


class SampleClock:
    """Sample times [ns] one period apart on the caller's clock (ROS time: sim time works).

    ``due(now_ns)`` returns every sample time not yet handed out up to ``now_ns``: one per call
    on time, a burst after a stall. A stall longer than ``backlog_ns`` overflows the sensor's
    buffer: the older samples are lost (counted in ``dropped``) and sampling goes on from
    ``now_ns``; so does a clock that went back (a replay restarting its /clock).
    """

    def __init__(self, period_ns: int, backlog_ns: int) -> None:
        if period_ns <= 0 or backlog_ns < period_ns:
            raise ValueError(f'period {period_ns} ns must be > 0 and the backlog '
                             f'{backlog_ns} ns at least one period')
        self.period_ns = period_ns
        self.backlog_ns = backlog_ns
        self.dropped = 0
        self._next: int | None = None

    def due(self, now_ns: int) -> list[int]:
        if self._next is None or now_ns < self._next - self.period_ns:
            self._next = now_ns
        elif now_ns - self._next > self.backlog_ns:
            keep_from = now_ns - self.backlog_ns
            lost = -(-(keep_from - self._next) // self.period_ns)     # ceil
            self.dropped += lost
            self._next += lost * self.period_ns
        stamps = list(range(self._next, now_ns + 1, self.period_ns))
        if stamps:
            self._next = stamps[-1] + self.period_ns
        return stamps
