"""Ring buffer of joint samples, the hold-window statistics of `capture_joints`, and the
message counts by stamp second that line a publisher's count up with a subscriber's."""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
import math

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.errors import ErrorCode

Array = NDArray[np.float64]


class Rejection(str, Enum):
    """Why a joint_states message was dropped."""

    NON_FINITE = 'non_finite'
    LENGTH_MISMATCH = 'length_mismatch'
    UNKNOWN_JOINTS = 'unknown_joints'


class JointRingBuffer:
    """Fixed-capacity buffer of (time [s], positions [rad]) in a fixed joint order."""

    def __init__(self, joint_names: list[str] | None, capacity: int) -> None:
        self.joint_names = list(joint_names) if joint_names else None
        self._capacity = capacity
        self._times = np.full(capacity, -math.inf)
        self._positions: Array | None = None
        self._next = 0
        self.count = 0
        self.latest_time = -math.inf
        self.rejected = {r: 0 for r in Rejection}

    def add(self, t: float, names: list[str], positions: list[float]) -> Rejection | None:
        """Store one message (reordered to the buffer's joint order) or say why not."""
        if len(names) != len(positions) or not names:
            return self._reject(Rejection.LENGTH_MISMATCH)
        if self.joint_names is None:
            self.joint_names = list(names)
        if names != self.joint_names:       # 1 kHz: the common case (same order) stays cheap
            if len(names) != len(self.joint_names) or set(names) != set(self.joint_names):
                return self._reject(Rejection.UNKNOWN_JOINTS)
            order = {n: i for i, n in enumerate(names)}
            positions = [positions[order[n]] for n in self.joint_names]
        if not all(map(math.isfinite, positions)):
            return self._reject(Rejection.NON_FINITE)
        if self._positions is None:
            self._positions = np.zeros((self._capacity, len(positions)))
        self._times[self._next] = t
        self._positions[self._next] = positions
        self._next = (self._next + 1) % self._capacity
        self.count += 1
        self.latest_time = max(self.latest_time, t)
        return None

    def _reject(self, reason: Rejection) -> Rejection:
        self.rejected[reason] += 1
        return reason

    def window(self, t0: float, t1: float) -> tuple[Array, Array]:
        """Samples with t0 <= t <= t1: times (k,), positions (k, n)."""
        if self._positions is None:
            return np.empty(0), np.empty((0, len(self.joint_names or [])))
        mask = (self._times >= t0) & (self._times <= t1)
        order = np.argsort(self._times[mask])
        return self._times[mask][order], self._positions[mask][order]


class StampMarks:
    """Counts messages and marks each whole second of their header stamps.

    ``mark`` is ``(second, count)``: the latest whole second S [s] of stamp time a message
    reached, and how many messages came before the first one stamped at or after S. A
    publisher and a subscriber that both keep one agree on which messages lie before S
    (stamps increase, and a reliable topic delivers one publisher's messages in order), so
    for two seconds both have marked, the difference of their counts is exactly the messages
    lost between those stamps: start-up, shut-down and stalls do not enter it.
    """

    def __init__(self) -> None:
        self.count = 0
        self.mark: tuple[int, int] = (0, 0)
        self._second = None

    def add(self, stamp_sec: int) -> None:
        """Count one message with header stamp seconds ``stamp_sec``."""
        if stamp_sec != self._second:
            self._second = stamp_sec
            self.mark = (stamp_sec, self.count)     # one tuple: read whole from any thread
        self.count += 1


class StampGaps:
    """Gaps between consecutive header stamps of a stream with a nominal rate.

    ``missing`` adds up ``round(gap * rate) - 1`` over all gaps: what a stamp-gap count calls
    missing. A subscriber's figure mixes messages lost on the way with the publisher's own
    stalls (a late tick, then a catch-up); the publisher's figure is the stalls alone.
    """

    def __init__(self, rate_hz: float) -> None:
        self._rate = rate_hz
        self._last: float | None = None
        self.missing = 0
        self._max_gap = 0.0

    def add(self, stamp: float) -> None:
        """One message stamped ``stamp`` [s]."""
        if self._last is not None:
            gap = stamp - self._last
            self.missing += max(0, round(gap * self._rate) - 1)
            self._max_gap = max(self._max_gap, gap)
        self._last = stamp

    def take_max_gap(self) -> float:
        """The largest gap [s] since the previous call (0.0 if none), and start over."""
        gap, self._max_gap = self._max_gap, 0.0
        return gap


@dataclass(frozen=True)
class HoldCapture:
    ok: bool
    code: ErrorCode           # SUCCESS, NO_DATA or MOVING
    message: str
    mean: Array
    std: Array
    count: int
    span: float               # [s]


# A hold that got too few samples goes on for up to this many more windows: on a loaded
# machine the driver's 1 kHz stream arrives thinned (its timer misses ticks), and a capture
# must give the same verdict as on an idle one; a driver that does not publish still fails.
HOLD_EXTENSIONS = 4


def samples_needed(duration: float, expected_rate: float, min_fraction: float) -> int:
    """The samples a hold of ``duration`` [s] must average at least."""
    return max(2, int(min_fraction * expected_rate * duration))


def hold_statistics(times: Array, positions: Array, duration: float, expected_rate: float,
                    min_fraction: float, max_std: float,
                    joint_names: list[str], window_s: float | None = None) -> HoldCapture:
    """Mean and spread of a hold window of ``duration`` [s] (collected over ``window_s``
    [s] >= duration when the hold went on for missing samples); refuses too few samples
    or a moving arm."""
    count = len(times)
    span = float(times[-1] - times[0]) if count > 1 else 0.0
    width = positions.shape[1] if positions.ndim == 2 else 0
    mean = positions.mean(axis=0) if count else np.full(width, math.nan)
    std = positions.std(axis=0, ddof=1) if count > 1 else np.full(width, math.nan)
    if count > 1 and np.max(std) > max_std:     # motion explains missing samples too
        worst = int(np.argmax(std))
        return HoldCapture(False, ErrorCode.MOVING, (
            f'the arm is moving: {joint_names[worst]} spread {std[worst]:.2e} rad > '
            f'{max_std:.1e} rad; wait until the motion ends, then capture again'),
            mean, std, count, span)
    needed = samples_needed(duration, expected_rate, min_fraction)
    if count < needed:
        empty = np.full(width, math.nan)
        return HoldCapture(False, ErrorCode.NO_DATA, (
            f'only {count} joint_states samples in {_held(duration, window_s)} (need {needed}); '
            'is the robot driver (mock_robot) publishing joint_states?'),
            empty, empty, count, span)
    return HoldCapture(True, ErrorCode.SUCCESS, f'{count} samples over {span:.3f} s', mean, std,
                       count, span)


def _held(duration: float, window_s: float | None) -> str:
    """'0.200 s', or '1.000 s (the 0.200 s hold went on)' when it went on for samples."""
    if window_s is None or window_s <= duration * (1.0 + 1e-9):
        return f'{duration:.3f} s'
    return f'{window_s:.3f} s (the {duration:.3f} s hold went on)'
