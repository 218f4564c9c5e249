"""Proximity probe: voltage to distance through a calibration table, with range checks."""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
import math

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode


@dataclass(frozen=True)
class ProbeCurve:
    """Calibration table of an inductive probe: voltage [V] against gap [m]."""

    distance: tuple[float, ...]   # increasing [m]
    voltage: tuple[float, ...]    # [V], monotonic

    @property
    def min_range(self) -> float:
        return self.distance[0]

    @property
    def max_range(self) -> float:
        return self.distance[-1]

    def to_voltage(self, gap: float) -> float:
        """Sensor output for a gap; saturates at the range ends like the real probe."""
        g = min(max(gap, self.min_range), self.max_range)
        return float(np.interp(g, self.distance, self.voltage))

    def to_distance(self, voltage: float) -> float:
        """Gap for a voltage by linear interpolation in the table (voltage may decrease)."""
        v = np.asarray(self.voltage)
        d = np.asarray(self.distance)
        if v[0] > v[-1]:
            v, d = v[::-1], d[::-1]
        return float(np.interp(voltage, v, d))


class ReadingStatus(IntEnum):
    """Matches cobot_calib_msgs/msg/ProximityReading STATUS_*."""

    OK = 0
    BELOW_RANGE = 1
    ABOVE_RANGE = 2
    INVALID = 3


@dataclass(frozen=True)
class Reading:
    distance: float   # [m]; NaN unless status is OK
    status: ReadingStatus


def read_distance(curve: ProbeCurve, voltage: float, saturation_margin: float) -> Reading:
    """Convert one voltage; readings within `saturation_margin` [m] of a range end are
    treated as saturated, because a saturated probe sits on its rail plus noise."""
    if not math.isfinite(voltage):
        return Reading(math.nan, ReadingStatus.INVALID)
    d = curve.to_distance(voltage)
    if d <= curve.min_range + saturation_margin:
        return Reading(math.nan, ReadingStatus.BELOW_RANGE)
    if d >= curve.max_range - saturation_margin:
        return Reading(math.nan, ReadingStatus.ABOVE_RANGE)
    return Reading(d, ReadingStatus.OK)


def curve_from_lists(distance: list[float], voltage: list[float]) -> ProbeCurve:
    """Validated calibration table; raises ValueError with what to fix."""
    d = np.asarray(distance, dtype=float)
    v = np.asarray(voltage, dtype=float)
    if d.shape != v.shape or d.size < 2:
        raise ValueError('calibration_distance and calibration_voltage need the same length >= 2')
    if not (np.all(np.diff(d) > 0) and (np.all(np.diff(v) > 0) or np.all(np.diff(v) < 0))):
        raise ValueError('calibration table must be strictly monotonic in distance and voltage')
    return ProbeCurve(tuple(d.tolist()), tuple(v.tolist()))


@dataclass(frozen=True)
class ProbeAverage:
    """A window of readings averaged (what probe/average answers); truthy when SUCCESS."""

    code: ErrorCode                # SUCCESS, NO_DATA or OUT_OF_RANGE
    message: str
    distance: float = math.nan     # mean of the in-range readings [m]; NaN unless SUCCESS
    std: float = math.nan          # their standard deviation (n - 1) [m]; NaN unless SUCCESS
    sample_count: int = 0          # in-range readings averaged
    rejected_count: int = 0        # readings left out (out of range or invalid)
    status: ReadingStatus = ReadingStatus.OK   # OUT_OF_RANGE: the status most rejected had

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS

    def reading(self) -> Reading | None:
        """The averaged Reading (out of range: BELOW_RANGE / ABOVE_RANGE and NaN); None when
        the window gave none: no readings, or mostly INVALID ones (a broken probe signal)."""
        if self.code == ErrorCode.SUCCESS:
            return Reading(self.distance, ReadingStatus.OK)
        if self.code == ErrorCode.OUT_OF_RANGE and self.status in (
                ReadingStatus.BELOW_RANGE, ReadingStatus.ABOVE_RANGE):
            return Reading(math.nan, self.status)
        return None


Sample = tuple[int, float, ReadingStatus]    # (stamp [ns], distance [m], status)


def average_window(samples, t0_ns: int, duration: float) -> list[Sample]:
    """The samples, in their order, that a window opened at ``t0_ns`` [ns] lasting
    ``duration`` [s] holds (both ends included)."""
    t0 = t0_ns * 1e-9
    t1 = t0 + duration
    return [sample for sample in samples if t0 <= sample[0] * 1e-9 <= t1]


def average(window: list[Sample], duration: float) -> ProbeAverage:
    """The window's readings averaged, by the majority rule: the in-range readings must be
    more than half of the window, else the window is OUT_OF_RANGE with the status most of the
    rejected readings had (INVALID too: then :meth:`ProbeAverage.reading` is None)."""
    valid = np.array([d for _, d, s in window if s == ReadingStatus.OK])
    rejected = [s for _, _, s in window if s != ReadingStatus.OK]
    counts = {'sample_count': int(valid.size), 'rejected_count': len(rejected)}
    if not window:
        return ProbeAverage(ErrorCode.NO_DATA, f'no probe readings in {duration:.3f} s; '
                            'is probe/voltage being published?', **counts)
    if rejected and len(rejected) >= len(window) / 2:
        status = max(set(rejected), key=rejected.count)
        side = {ReadingStatus.BELOW_RANGE: 'the target is closer than the probe range; ',
                ReadingStatus.ABOVE_RANGE: 'the target is beyond the probe range; '}.get(
                    status, 'the probe signal is not a number; check the probe and its cable, '
                    'then ')
        return ProbeAverage(ErrorCode.OUT_OF_RANGE, (
            f'{len(rejected)} of {len(window)} readings out of range ({status.name}): '
            f'{side}move the probe and measure again'), status=ReadingStatus(status), **counts)
    return ProbeAverage(ErrorCode.SUCCESS, f'{valid.size} readings, {len(rejected)} rejected',
                        float(valid.mean()), float(valid.std(ddof=1)) if valid.size > 1 else 0.0,
                        **counts)
