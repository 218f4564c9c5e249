"""Height correction of the user plane (SurfaceModel, fit_surface) and the user <-> base maps."""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import apply, invert
from cobot_calib_ros.core.user_frame.checks import _prepare
from cobot_calib_ros.core.user_frame.geometry import _rms, Array

_TERMS = {
    0: ((0, 0),),
    1: ((0, 0), (1, 0), (0, 1)),
    2: ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)),
}


@dataclass(frozen=True, eq=False)
class SurfaceModel:
    """Height correction in the user frame: dz(x, y) = sum_k c_k x^px_k y^py_k [m].

    ``coefficients[k]`` is in m^(1 - px - py). ``rms_before`` / ``rms_after`` are the RMS height
    residuals of the fitted points before and after the correction [m] (in-sample, so
    optimistic). Falsy when not valid.
    """

    powers_x: tuple[int, ...] = ()
    powers_y: tuple[int, ...] = ()
    coefficients: Array = field(default_factory=lambda: np.zeros(0))
    rms_before: float = math.inf
    rms_after: float = math.inf
    code: ErrorCode = ErrorCode.NO_DATA   # SUCCESS: a surface was fitted
    message: str = ''

    def height(self, x: ArrayLike, y: ArrayLike) -> Array:
        """Correction dz [m] at user-frame x, y [m]; zero when no surface was fitted."""
        if not self:
            return np.zeros(np.shape(x))
        terms = tuple(zip(self.powers_x, self.powers_y))
        V = _design(np.asarray(x, dtype=float), np.asarray(y, dtype=float), terms)
        return V @ self.coefficients

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


def fit_surface(p_user: ArrayLike, p_base: ArrayLike, M_base_user: Array,
                order: int | None = None, *, names: Sequence[str] | None = None
                ) -> SurfaceModel:
    """Fit dz(x, y) = z_measured - z_nominal of the points in the user frame [m].

    The measured points are taken into the user frame with the inverse of ``M_base_user``,
    the map the calibration converts with (rigid, or the affine M of five_point_lsq); dz is
    fitted over the nominal x, y by least squares. ``order`` 0 (offset), 1 (1, x, y) or 2
    (adds x^2, xy, y^2); None picks the highest order that leaves at least one
    spare degree of freedom: 3 points -> 0, 4-6 points (the paper's 5) -> 1, 7+ -> 2. After a
    rigid fit the order-1 part is nearly zero (the fit took the tilt): the curvature terms need
    7 or more points. ``names`` (default P1..Pn) name the points in messages.
    """
    pu, pb, _, failure = _prepare(p_user, p_base, names)
    if failure is not None:
        return SurfaceModel(code=failure.code, message=failure.message)
    chosen = _surface_order(len(pu), order)
    if chosen is None:
        return SurfaceModel(code=ErrorCode.TOO_FEW_POINTS, message=(
            f'{len(pu)} points cannot fit an order-{order} surface with a spare degree of '
            'freedom; touch more markers or lower order'))
    terms = _TERMS[chosen]
    dz = apply(np.linalg.inv(M_base_user), pb)[:, 2] - pu[:, 2]
    V = _design(pu[:, 0], pu[:, 1], terms)
    coefficients, _, rank, _ = np.linalg.lstsq(V, dz, rcond=None)
    if rank < len(terms):
        return SurfaceModel(code=ErrorCode.DEGENERATE_POINTS, message=(
            f'the marker x, y layout cannot fit an order-{chosen} surface; spread the markers '
            'over the plane'))
    return SurfaceModel(tuple(p for p, _ in terms), tuple(p for _, p in terms), coefficients,
                        _rms(dz), _rms(dz - V @ coefficients), ErrorCode.SUCCESS,
                        f'order-{chosen} height correction from {len(pu)} points')


def user_to_base(T_base_user: Array, points: ArrayLike,
                 surface: SurfaceModel | None = None) -> Array:
    """Map user-frame points (N, 3) or (3,) [m] to base, first adding dz(x, y) along user z.

    ``T_base_user`` may be rigid or the affine ``FrameFit.M``."""
    p = np.array(points, dtype=float)
    if surface:
        p[..., 2] += surface.height(p[..., 0], p[..., 1])
    return apply(T_base_user, p)


def base_to_user(T_base_user: Array, points: ArrayLike,
                 surface: SurfaceModel | None = None) -> Array:
    """Inverse of :func:`user_to_base` for a rigid ``T_base_user``: base points [m] to user,
    then remove dz(x, y). (For an affine M, map with ``np.linalg.inv(M)`` instead.)"""
    p = apply(invert(T_base_user), points)
    if surface:
        p[..., 2] -= surface.height(p[..., 0], p[..., 1])
    return p


def _surface_order(n_points: int, order: int | None) -> int | None:
    if order is None:
        return max(o for o, terms in _TERMS.items() if len(terms) < n_points)
    if order not in _TERMS:
        raise ValueError(f'surface order must be one of {sorted(_TERMS)}, got {order!r}')
    return order if len(_TERMS[order]) < n_points else None


def _design(x: Array, y: Array, terms: tuple[tuple[int, int], ...]) -> Array:
    return np.stack([x ** px * y ** py for px, py in terms], axis=-1)
