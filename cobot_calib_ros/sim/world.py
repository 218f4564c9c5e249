"""The true cell: where the user frame really is, the uneven table, the real marker heights.

Ground truth that a real cell never tells; only the mock robot and tests read it. Metres.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
import math

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import Marker

Array = NDArray[np.float64]


@dataclass(frozen=True)
class HeightField:
    """Table height error dz(x, y) [m] over the user-frame xy plane [m]."""

    amplitude: float = 3.0e-4
    wavelength: float = 0.8
    tilt: tuple[float, float] = (0.0, 0.0)  # dz/dx, dz/dy [m/m]
    phase: tuple[float, float] = (0.0, 0.0)  # [rad]

    def __call__(self, x: Array | float, y: Array | float) -> Array:
        k = 2.0 * math.pi / self.wavelength
        wave = np.sin(k * np.asarray(x) + self.phase[0]) * np.sin(k * np.asarray(y) + self.phase[1])
        return self.amplitude * wave + self.tilt[0] * np.asarray(x) + self.tilt[1] * np.asarray(y)


@dataclass(frozen=True)
class TrueMarker:
    """A nominal marker as it really stands: on the uneven table, slightly off in height."""

    nominal: Marker
    base_z: float          # true z of the table under it, user frame [m]
    height_error: float    # true height minus the nominal size[2] [m]

    @property
    def name(self) -> str:
        return self.nominal.name

    @property
    def top_z(self) -> float:
        return self.base_z + self.nominal.size[2] + self.height_error

    @property
    def true_top(self) -> Array:
        return np.array([*self.nominal.xy, self.top_z])

    def box(self) -> tuple[Array, Array]:
        half = np.array(self.nominal.size[:2]) / 2.0
        xy = np.array(self.nominal.xy)
        return np.array([*(xy - half), self.base_z]), np.array([*(xy + half), self.top_z])


def ray_box_distance(origin: Array, direction: Array, lo: Array, hi: Array) -> float:
    """Distance along a unit ray to where it first enters one of the axis-aligned boxes
    ``lo``..``hi`` ((3,) for one box, (N, 3) for N); inf if it misses them all, 0 if the ray
    starts inside one (a probe pushed into a marker reads as touching it)."""
    lo, hi = np.atleast_2d(lo), np.atleast_2d(hi)
    with np.errstate(divide='ignore', invalid='ignore'):
        t1 = (lo - origin) / direction
        t2 = (hi - origin) / direction
    t1 = np.where(np.isnan(t1), -np.inf, t1)
    t2 = np.where(np.isnan(t2), np.inf, t2)
    t_near = np.minimum(t1, t2).max(axis=1)
    t_far = np.maximum(t1, t2).min(axis=1)
    hit = (t_near <= t_far) & (t_far >= 0.0)
    if not hit.any():
        return math.inf
    return float(np.maximum(t_near[hit], 0.0).min())


@dataclass(frozen=True)
class World:
    """The true cell: where the user frame is and what stands on the table."""

    T_base_user: Array
    markers: tuple[TrueMarker, ...]
    height_field: HeightField

    def marker(self, name: str) -> TrueMarker | None:
        return next((m for m in self.markers if m.name == name), None)

    @property
    def point_names(self) -> list[str]:
        return [m.name for m in self.markers]

    def true_points_base(self) -> Array:
        """(N, 3) true marker top-face centres in the base frame [m]."""
        return frames.apply(self.T_base_user, np.array([m.true_top for m in self.markers]))

    def probe_gap(self, T_base_tool: Array) -> float:
        """Gap [m] along the tool z axis from the probe tip to the nearest marker face."""
        if not self.markers:
            return math.inf
        T_user_tool = self._T_user_base @ T_base_tool
        return ray_box_distance(T_user_tool[:3, 3], T_user_tool[:3, 2], *self._boxes)

    # cached: mock_robot asks for a probe gap 200 times a second
    @cached_property
    def _T_user_base(self) -> Array:
        return frames.invert(self.T_base_user)

    @cached_property
    def _boxes(self) -> tuple[Array, Array]:
        """(lo, hi), each (N, 3): the markers' boxes, user frame [m]."""
        corners = [m.box() for m in self.markers]
        return np.array([lo for lo, _ in corners]), np.array([hi for _, hi in corners])
