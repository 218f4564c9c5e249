"""Ids of stored records (calibrations, collections, hand-eye, kinematic calibrations)."""
from __future__ import annotations

import time


def record_id(suffix: str, wall_ns: int | None = None) -> str:
    """'<UTC date>T<time>.<ns>Z-<suffix>', e.g. '20261123T023546.123456789Z-rigid': sorts by
    time and is a file name stem. Wall clock, not ROS time: it stays unique when a simulated
    clock is paused or replayed."""
    wall_ns = time.time_ns() if wall_ns is None else wall_ns
    return (time.strftime('%Y%m%dT%H%M%S', time.gmtime(wall_ns // 1_000_000_000))
            + f'.{wall_ns % 1_000_000_000:09d}Z-{suffix}')


def utc_text(wall_ns: int) -> str:
    """'YYYY-MM-DD HH:MM:SS UTC' of a wall-clock stamp [ns] (for people: notes in files)."""
    return time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime(wall_ns // 1_000_000_000))
