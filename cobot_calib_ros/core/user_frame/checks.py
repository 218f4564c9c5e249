"""Input checks of a point-pair set, and the point names messages use (P1..Pn by default).

Data problems come back as a :class:`Failure`; wrong shapes and a wrong number of names are
programmer errors and raise.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.units import MAX_CELL_LENGTH
from cobot_calib_ros.core.user_frame.geometry import _as_points, Array, collinearity

DUPLICATE_TOL = 1e-6      # [m] two points closer than this are the same point
MIN_COLLINEARITY = 1e-3   # s_min / s_max of the in-plane spread below this: collinear
MAX_COORDINATE = 1.0e3
"""[m] Coordinates beyond this are refused: no robot cell is a kilometre wide."""

Names = tuple[str, ...]


def point_names(n_points: int, names: Sequence[str] | None = None) -> Names:
    """The names of ``n_points`` points: ``names`` as given, or P1..Pn when None or empty."""
    if not names:
        return tuple(f'P{i + 1}' for i in range(n_points))
    if isinstance(names, str) or len(names) != n_points:
        raise ValueError(f'names must be a sequence of {n_points} strings, one per point, '
                         f'got {names!r}')
    return tuple(str(name) for name in names)


def _prepare(p_user: ArrayLike, p_base: ArrayLike, names: Sequence[str] | None,
             n_plane: int | None = None) -> tuple[Array, Array, Names, Failure | None]:
    """The point arrays, their names and the first data problem (or None)."""
    pu, pb = _as_points(p_user, 'p_user'), _as_points(p_base, 'p_base')
    labels = point_names(len(pu), names) if len(pu) == len(pb) else point_names(len(pu))
    return pu, pb, labels, _check_points(pu, pb, n_plane, labels)


def _check_points(pu: Array, pb: Array, n_plane: int | None, names: Names
                  ) -> Failure | None:
    """The first data problem of a point-pair set, or None. ``n_plane``: points that span."""
    if len(pu) != len(pb):
        return Failure(ErrorCode.INVALID_INPUT, f'got {len(pu)} user points and {len(pb)} '
                       'base points; give one measured base point per nominal user point')
    if len(pu) < 3:
        return Failure(ErrorCode.TOO_FEW_POINTS, f'got {len(pu)} point(s); touch at least '
                       'three markers that are not on one line')
    for frame, points in (('user', pu), ('base', pb)):
        failure = _check_finite(points, frame, names)
        if failure is not None:
            return failure
    failure = _check_millimetres(pu, pb)
    if failure is not None:
        return failure
    for frame, points in (('user', pu), ('base', pb)):
        failure = _check_duplicates(points, frame, names)
        if failure is not None:
            return failure
    return _check_collinear(pu[:n_plane], pb[:n_plane], n_plane, names)


def _check_millimetres(pu: Array, pb: Array) -> Failure | None:
    """Both sets beyond any cell: both in millimetres. (One set alone in millimetres fits, and
    the plausibility gate says which from the fit's scale or residuals.)"""
    far = [float(np.abs(p).max()) for p in (pu, pb)]
    if min(far) <= MAX_CELL_LENGTH:
        return None
    return Failure(ErrorCode.INVALID_INPUT, (
        f'the points look like millimetres (user points up to {far[0]:g}, base points up to '
        f'{far[1]:g} from the origin, beyond the {MAX_CELL_LENGTH:g} m of any cell); lengths '
        'are in metres: divide both by 1000'))


def _check_finite(points: Array, frame: str, names: Names) -> Failure | None:
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        return Failure(ErrorCode.INVALID_INPUT, f'{frame} point {names[bad[0]]} is not finite '
                       f'({points[bad[0]].tolist()}); re-measure it or leave it out')
    far = np.flatnonzero((np.abs(points) > MAX_COORDINATE).any(axis=1))
    if len(far):     # beyond any cell, and squares of ~1e154 m overflow inside the SVD
        return Failure(ErrorCode.INVALID_INPUT, f'{frame} point {names[far[0]]} is '
                       f'{points[far[0]].tolist()} m, beyond {MAX_COORDINATE:g} m from the '
                       'origin; points are in metres (not millimetres?)')
    return None


def _check_duplicates(points: Array, frame: str, names: Names) -> Failure | None:
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    i, j = np.nonzero(np.triu(d < DUPLICATE_TOL, k=1))
    if len(i) == 0:
        return None
    hint = ' (did the robot move between the two touches?)' if frame == 'base' else ''
    return Failure(ErrorCode.DEGENERATE_POINTS, f'{frame} points {names[i[0]]} and '
                   f'{names[j[0]]} coincide ({d[i[0], j[0]] * 1e3:.4f} mm apart); each point '
                   f'must be a different marker{hint}')


def _check_collinear(pu: Array, pb: Array, n_plane: int | None, names: Names
                     ) -> Failure | None:
    value = min(collinearity(pu), collinearity(pb))
    if value >= MIN_COLLINEARITY:
        return None
    which = (f'the first {n_plane} points ({", ".join(names[:n_plane])})' if n_plane
             else 'the points')
    return Failure(ErrorCode.DEGENERATE_POINTS, f'{which} are (nearly) collinear (collinearity '
                   f'{value:.2e} < {MIN_COLLINEARITY:.0e}); touch at least three markers that '
                   'are not on one line')

