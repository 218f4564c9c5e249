"""Small shared helpers of the user-frame package: array checks, spreads, formatting."""
from __future__ import annotations

import math
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]
Estimator = Callable[[Array, Array], Array]


def collinearity(points: ArrayLike) -> float:
    """s2 / s1 of the centred points' singular values: 0 collinear .. 1 isotropic in-plane."""
    s = _spread(_as_points(points, 'points'))
    return float(s[1] / s[0]) if s[0] > 0.0 else 0.0


def _as_points(points: ArrayLike, name: str) -> Array:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f'{name} must be an (N, 3) array [m], got shape {p.shape}')
    return p


def _spread(points: Array) -> Array:
    return np.linalg.svd(points - points.sum(axis=0) / len(points), compute_uv=False)


def _rms(values: Array) -> float:
    """RMS of vector norms (rows of a 2-D array) or of scalars [same unit]."""
    v = np.asarray(values, dtype=float)
    squares = (v ** 2).sum(axis=1) if v.ndim == 2 else v ** 2
    return float(math.sqrt(squares.mean()))


def _join(*parts: str) -> str:
    return '; '.join(p for p in parts if p)
