"""Ring buffer of joint samples and the hold-window statistics of `capture_joints`."""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
import math

import numpy as np
from numpy.typing import NDArray

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
        if len(names) != len(self.joint_names) or set(names) != set(self.joint_names):
            return self._reject(Rejection.UNKNOWN_JOINTS)
        q = np.asarray(positions, dtype=float)
        if not np.all(np.isfinite(q)):
            return self._reject(Rejection.NON_FINITE)
        if names != self.joint_names:
            order = {n: i for i, n in enumerate(names)}
            q = q[[order[n] for n in self.joint_names]]
        if self._positions is None:
            self._positions = np.zeros((self._capacity, len(q)))
        self._times[self._next] = t
        self._positions[self._next] = q
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


@dataclass(frozen=True)
class HoldCapture:
    ok: bool
    reason: str               # '', 'no_data', 'moving'
    message: str
    mean: Array
    std: Array
    count: int
    span: float               # [s]


def hold_statistics(times: Array, positions: Array, duration: float, expected_rate: float,
                    min_fraction: float, max_std: float,
                    joint_names: list[str]) -> HoldCapture:
    """Mean and spread of a hold window; refuses too few samples or a moving arm."""
    count = len(times)
    span = float(times[-1] - times[0]) if count > 1 else 0.0
    width = positions.shape[1] if positions.ndim == 2 else 0
    mean = positions.mean(axis=0) if count else np.full(width, math.nan)
    std = positions.std(axis=0, ddof=1) if count > 1 else np.full(width, math.nan)
    if count > 1 and np.max(std) > max_std:     # motion explains missing samples too
        worst = int(np.argmax(std))
        return HoldCapture(False, 'moving', (
            f'the arm is moving: {joint_names[worst]} spread {std[worst]:.2e} rad > '
            f'{max_std:.1e} rad; wait until the motion ends, then capture again'),
            mean, std, count, span)
    needed = max(2, int(min_fraction * expected_rate * duration))
    if count < needed:
        empty = np.full(width, math.nan)
        return HoldCapture(False, 'no_data', (
            f'only {count} joint_states samples in {duration:.3f} s (need {needed}); '
            'is the robot driver (mock_robot) publishing joint_states?'),
            empty, empty, count, span)
    return HoldCapture(True, '', f'{count} samples over {span:.3f} s', mean, std, count, span)
