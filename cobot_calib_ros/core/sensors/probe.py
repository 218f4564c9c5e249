"""Proximity probe: voltage to distance through a calibration table, with range checks."""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
import math

import numpy as np


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
