"""Calibration data: relative (tool coupled to precision spheres) and absolute (laser tracker).

Both copy their arrays read-only and raise ValueError, saying what to fix, on data that would
otherwise give NaN or a meaningless fit downstream.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def _joint_angles(q: ArrayLike) -> Array:
    a = np.array(q, dtype=float)
    if a.ndim != 2 or len(a) == 0:
        raise ValueError(f'q must be (m, n) joint angles [rad] with m >= 1, got shape {a.shape}')
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if len(bad):
        raise ValueError(f'q has NaN or inf in rows {bad[:10].tolist()}: drop those '
                         f'samples (a joint state was missing when they were recorded?)')
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class SphereObservations:
    """Joint angles with the tool centre coupled to one of several fixed spheres.

    q (m, n) [rad]; sphere (m,) int, the sphere of each row (any integer ids); known_distances
    ((i, j, D), ...) centre-to-centre distances D [m] between spheres i and j known beforehand
    (e.g. from a CMM). Without any, lengths are fixed only through the parameters held fixed.
    """

    q: Array
    sphere: NDArray[np.int_]
    known_distances: tuple[tuple[int, int, float], ...] = ()

    def __post_init__(self) -> None:
        q = _joint_angles(self.q)
        sphere = np.array(self.sphere)
        if sphere.shape != (len(q),) or not np.issubdtype(sphere.dtype, np.integer):
            raise ValueError(f'sphere must be ({len(q)},) integer ids, one per row of q; got '
                             f'{sphere.dtype} {sphere.shape}')
        sphere.setflags(write=False)
        ids, counts = np.unique(sphere, return_counts=True)
        few = ids[counts < 2]
        if len(few):
            raise ValueError(f'spheres {few.tolist()} have fewer than 2 rows: record more '
                             f'poses on them or drop their rows')
        distances = tuple((int(i), int(j), float(d)) for i, j, d in self.known_distances)
        for i, j, d in distances:
            if i == j or i not in ids or j not in ids:
                raise ValueError(f'known distance ({i}, {j}) must join two different spheres '
                                 f'of the data {ids.tolist()}')
            if not np.isfinite(d) or d <= 0.0:
                raise ValueError(f'known distance ({i}, {j}) must be > 0 [m], got {d}')
        object.__setattr__(self, 'q', q)
        object.__setattr__(self, 'sphere', sphere)
        object.__setattr__(self, 'known_distances', distances)

    @property
    def spheres(self) -> tuple[int, ...]:
        """Sphere ids present, sorted."""
        return tuple(int(s) for s in np.unique(self.sphere))


@dataclass(frozen=True)
class PositionObservations:
    """Joint angles q (m, n) [rad] with measured tool positions p (m, 3) [m] (tracker frame)."""

    q: Array
    p: Array

    def __post_init__(self) -> None:
        q = _joint_angles(self.q)
        p = np.array(self.p, dtype=float)
        if p.shape != (len(q), 3):
            raise ValueError(f'p must be ({len(q)}, 3) positions [m], got {p.shape}')
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        if len(bad):
            raise ValueError(f'p has NaN or inf in rows {bad[:10].tolist()}: drop those samples '
                             f'(tracker lost the reflector?)')
        p.setflags(write=False)
        object.__setattr__(self, 'q', q)
        object.__setattr__(self, 'p', p)
