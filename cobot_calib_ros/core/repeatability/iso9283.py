"""Positioning repeatability (ISO 9283) measured with a single-axis proximity probe.

References: the seed paper on Sawyer user-frame calibration, section 3 eqs (9)-(14) for the
per-point statistics, section 4.3 eq (15) for the range correction FF_i,n; ISO 9283:1998
section 7.2.2 for the three-dimensional repeatability RP_l.

Units are metres throughout. Probe readings ``d`` form an (m_points, n_cycles) array: row i is
point P_i, column n is cycle n. NaN marks a measurement not taken yet, so a trial in progress
can be passed as is.

Probe sign convention (used by every function here): the probe reads the gap g [m] between its
tip and the marker along its axis. Moving the tool *away* from the marker by s increases the
gap by s; moving it *closer* by s decreases the gap by s. In the paper's z set-up the probe
looks down at the marker, so "away" is +z and "closer" is -z.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode

Array = NDArray[np.float64]
Direction = Literal['away', 'closer']
DIRECTIONS: tuple[Direction, ...] = ('away', 'closer')
AXES = ('x', 'y', 'z')  # probed axis of a trial, in the user frame


@dataclass(frozen=True, eq=False)
class PointStats:
    """Per-point repeatability of eqs (9)-(14); arrays have shape (m,), values in metres.

    Only complete cycles (every point measured) are used, so all points share the same
    ``cycles``. With ``cycles < 2`` the sample deviation of eq (12) is undefined and
    ``sigma``, ``rp`` and ``rp_all`` are NaN; the instance is then falsy (``code``
    TOO_FEW_POINTS, ``message`` says how many cycles it has). Note that with
    exactly 2 cycles D_i,1 == D_i,2, so ``sigma`` is 0 and ``rp`` is |d_i,1 - d_i,2| / 2.
    """

    mean_distance: Array   # d-bar_i, eq (9) [m]
    mean_deviation: Array  # D-bar_i, eq (11) [m]
    sigma: Array           # sigma_i, eq (12), n - 1 in the denominator [m]
    rp: Array              # RP_i = D-bar_i + 3 sigma_i, eq (13) [m]
    rp_all: float          # mean of RP_i over the m points, eq (14) [m]
    cycles: int            # number of complete cycles used
    code: ErrorCode = ErrorCode.SUCCESS
    message: str = ''

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


class RangeCorrection(NamedTuple):
    """Offset FF_i,n of eq (15) [m] (>= 0) and where it moved the commanded point."""

    ff: float
    direction: Direction | None


def complete_cycles(d: ArrayLike) -> NDArray[np.bool_]:
    """(n,) mask of the columns of an (m, n) array [m] in which every point is finite."""
    return np.all(np.isfinite(_as_distances(d)), axis=0)


def deviations(d: ArrayLike) -> Array:
    """D_i,n = |d_i,n - d-bar_i| of eqs (9)-(10) for a fully measured (m, k) array [m]."""
    dk = _as_distances(d)
    return np.abs(dk - dk.mean(axis=1, keepdims=True))


def overall_rp(rp: ArrayLike) -> float:
    """RP_all of eq (14): the mean of the per-point RP_i [m] over the m points."""
    values = np.asarray(rp, dtype=float)
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f'expected a non-empty (m,) array, got shape {values.shape}')
    return float(values.mean())


def point_statistics(d: ArrayLike) -> PointStats:
    """Repeatability of each point from an (m, n) distance array [m], eqs (9)-(14).

    Columns with any NaN (a cycle not finished, or a lost measurement) are left out as a
    whole, so after k finished cycles the result equals that of the first k columns.
    """
    dist = _as_distances(d)
    dk = dist[:, complete_cycles(dist)]
    m, k = dk.shape
    nan = np.full(m, math.nan)
    if k == 0:
        return PointStats(nan, nan.copy(), nan.copy(), nan.copy(), math.nan, 0,
                          ErrorCode.TOO_FEW_POINTS, _too_few(0))
    dev = deviations(dk)
    mean_dev = dev.mean(axis=1)
    if k < 2:
        return PointStats(dk.mean(axis=1), mean_dev, nan, nan.copy(), math.nan, k,
                          ErrorCode.TOO_FEW_POINTS, _too_few(k))
    sigma = dev.std(axis=1, ddof=1)
    rp = mean_dev + 3.0 * sigma
    return PointStats(dk.mean(axis=1), mean_dev, sigma, rp, overall_rp(rp), k)


def _too_few(cycles: int) -> str:
    return (f'{cycles} complete cycle(s): the repeatability (eqs 12-14) needs at least 2; '
            'measure more cycles')


def correct_distance(d: float, ff: float, direction: Direction | None) -> float:
    """Refer a reading d [m] back to the uncorrected commanded point, eq (15).

    ``direction`` says where the offset ff [m] (>= 0) moved the commanded point:
    'closer' (commanded F_i,n - FF_i,n, the point was out of the probe range) reads a gap
    smaller by ff, so d + ff is returned; 'away' (commanded F_i,n + FF_i,n, the point was
    too close to the marker) reads a gap larger by ff, so d - ff is returned; None (no
    correction, ff must be 0) returns d.
    """
    if not ff >= 0.0:
        raise ValueError(f'ff must be >= 0 [m], got {ff}')
    if direction is None:
        if ff != 0.0:
            raise ValueError(f'ff = {ff} m given without a direction')
        return d
    if direction == 'closer':
        return d + ff
    if direction == 'away':
        return d - ff
    raise ValueError(f'direction must be one of {DIRECTIONS} or None, got {direction!r}')


def probe_offset(gap: float, g_min: float, g_max: float,
                 g_target: float | None = None) -> float:
    """Signed move [m] (positive = away from the marker) that turns ``gap`` into g_target.

    This is the per-point offset of the paper's section 2.1: in the z set-up F_i = z_R + the
    returned value. ``g_target`` defaults to the middle of the probe range [g_min, g_max] [m].
    A reading at or beyond a range limit is only a bound on the true gap, so the caller
    should move, measure again and repeat until the reading is strictly inside the range.
    A non-finite ``gap`` (no reading) returns NaN.
    """
    target = _target_gap(g_min, g_max, g_target)
    if not math.isfinite(gap):
        return math.nan
    return target - gap


def range_correction(predicted_gap: float, g_min: float, g_max: float, margin: float,
                     g_target: float | None = None) -> RangeCorrection:
    """FF_i,n [m] and its direction for a commanded point with the given predicted gap [m].

    The safe band is [g_min + margin, g_max - margin]. Below it the point is moved 'away'
    (too close: risk of touching the marker), above it 'closer' (out of the probe range),
    in both cases onto ``g_target`` (default: middle of the range), which must lie in the band.
    Inside the band: (0.0, None).
    """
    if not margin >= 0.0:
        raise ValueError(f'margin must be >= 0 [m], got {margin}')
    low, high = g_min + margin, g_max - margin
    target = _target_gap(low, high, g_target)
    if not math.isfinite(predicted_gap):
        raise ValueError(f'predicted gap must be finite, got {predicted_gap}')
    if predicted_gap < low:
        return RangeCorrection(target - predicted_gap, 'away')
    if predicted_gap > high:
        return RangeCorrection(predicted_gap - target, 'closer')
    return RangeCorrection(0.0, None)


def iso9283_rp_3d(positions: ArrayLike) -> float:
    """ISO 9283 (7.2.2) repeatability RP_l = l-bar + 3 S_l of n attained positions (n, 3) [m].

    Rows with a non-finite coordinate are dropped; fewer than 2 rows left returns NaN.
    """
    p = np.asarray(positions, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f'expected an (n, 3) array, got shape {p.shape}')
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 2:
        return math.nan
    lengths = np.linalg.norm(p - p.mean(axis=0), axis=1)
    return float(lengths.mean() + 3.0 * lengths.std(ddof=1))


def iso9283_rp_from_axes(dx: ArrayLike, dy: ArrayLike, dz: ArrayLike) -> float:
    """RP_l [m] from three single-axis runs of one point, each (n,) readings [m].

    With a single-axis probe each axis is measured in its own run (paper section 4.2). The
    runs are combined cycle by cycle: cycle j of the x, y and z runs is taken as one attained
    position (dx_j, dy_j, dz_j). This assumes the three runs are independent and equally
    conditioned; the result depends on that pairing, not only on each axis' spread. Constant
    per-axis offsets (marker positions) cancel, so raw readings or deviations both work.
    """
    axes = [np.asarray(a, dtype=float) for a in (dx, dy, dz)]
    if any(a.ndim != 1 for a in axes) or len({a.shape for a in axes}) != 1:
        shapes = [a.shape for a in axes]
        raise ValueError(f'expected three (n,) arrays of equal n, got shapes {shapes}')
    return iso9283_rp_3d(np.column_stack(axes))


def _as_distances(d: ArrayLike) -> Array:
    dist = np.asarray(d, dtype=float)
    if dist.ndim != 2 or dist.shape[0] == 0:
        raise ValueError(f'expected an (m_points, n_cycles) array, got shape {dist.shape}')
    return dist


def _target_gap(g_min: float, g_max: float, g_target: float | None) -> float:
    if not g_min < g_max:
        raise ValueError(f'empty gap range [{g_min}, {g_max}] m (check range and margin)')
    target = 0.5 * (g_min + g_max) if g_target is None else g_target
    if not g_min <= target <= g_max:
        raise ValueError(f'g_target {target} m is outside [{g_min}, {g_max}] m')
    return target
