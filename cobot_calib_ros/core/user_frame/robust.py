"""The robust method: a rigid fit that rejects gross outliers (a marker touched wrong).

Each point is tested against the prediction of the others (externally studentized residual of
the rigid fit): ``d`` is its leave-one-out prediction error [m], ``S = I + A C A^T`` its
covariance per unit noise (the point's own noise plus the uncertainty of the fit of the others
at that point: ``C`` is their unit pose covariance, ``A = [I, -[R p]x]``, see covariance.py),
and ``t^2 = d^T S^-1 d / s^2`` with ``s`` the noise per coordinate estimated from the residuals
of the others (or ``sigma_prior``). With Gaussian noise ``t^2 / 3`` follows F(3, 3k - 6) for k
other points (chi-square(3) / 3 with a prior), so the critical value follows from the target
false-rejection rate, split over the N points (Bonferroni): on clean data a good point is
rejected in at most ``false_rejection`` of calibrations, whatever the layout's size or leverage.
A point within ``threshold`` [m] of the prediction is never rejected.

Search: while any point fails the test against the others, drop the most significant one and
refit, keeping at least ``MIN_INLIERS`` (a failure left then: IMPLAUSIBLE_FIT). On clean data
only the first round runs, so its false-rejection rate is the test's. Outliers that hide each
other (e.g. two among five points) can pass: give ``sigma_prior``, or gate the result with
check_plausible and a residual limit.

Ambiguity: if swapping a rejected point for an inlier gives a set that passes the test AND
whose residual sum is within chance (1 % level) of the chosen set's, the data cannot tell the
two apart (e.g. a corner's height error on the paper's 5-point layout: dropping the opposite
corner leaves three points on a diagonal); the result is DEGENERATE_POINTS naming both. Passing
the test alone is not enough: with 4 points left the test has little power.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import skew
from cobot_calib_ros.core.user_frame.checks import _prepare, MIN_COLLINEARITY, Names
from cobot_calib_ros.core.user_frame.geometry import _join, Array
from cobot_calib_ros.core.user_frame.result import _failure, _rigid_fit, FrameFit

ROBUST_THRESHOLD = 5e-5
"""[m] Default floor of the robust method: a point this close to the prediction of the others is
never rejected, whatever the statistics say (sub-noise deviations of near noise-free data)."""
ROBUST_FALSE_REJECTION = 0.005
"""Default target rate of calibrations on clean data in which a good point is rejected."""
MIN_INLIERS = 4
_AMBIGUITY_LEVEL = 0.01   # a swap that raises the residual sum less than this test's value: tie
_MIN_VARIANCE = 1e-30     # [m^2] noise variance floor of noise-free data
_I3, _I6 = np.eye(3), np.eye(6)


def fit_robust(p_user: ArrayLike, p_base: ArrayLike, *, threshold: float = ROBUST_THRESHOLD,
               false_rejection: float = ROBUST_FALSE_REJECTION,
               sigma_prior: float | None = None, names: Sequence[str] | None = None
               ) -> FrameFit:
    """Rigid fit that rejects gross outliers by the studentized test of the module doc.

    ``threshold`` [m]: floor below which a point is never rejected. ``false_rejection``: target
    rate of calibrations of clean data that lose a good point. ``sigma_prior`` [m]: known noise
    per coordinate (default: estimated). ``names`` (default P1..Pn) name the points in messages.
    Residuals cover all points; rms, max and the covariance only the inliers.
    """
    pu, pb, labels, failure = _prepare(p_user, p_base, names)
    test = _Test(threshold, false_rejection, sigma_prior, len(pu))     # raises on bad options
    if failure is not None:
        return _failure('robust', failure)
    everything = np.ones(len(pu), dtype=bool)
    if len(pu) <= MIN_INLIERS:
        return _rigid_fit('robust', pu, pb, everything, sigma_prior, message=(
            f'only {len(pu)} points: at least {MIN_INLIERS} must remain after rejecting an '
            f'outlier, so {MIN_INLIERS + 1} are needed; plain rigid fit'))
    search = _Search(pu - pu.sum(axis=0) / len(pu), pb - pb.sum(axis=0) / len(pb), labels, test)
    keep, problem = search.drop(everything)
    if problem is None:
        problem = search.ambiguity(keep)
    if problem is not None:
        return _failure('robust', problem)
    outliers = tuple(int(i) for i in np.flatnonzero(~keep))
    return _rigid_fit('robust', pu, pb, keep, sigma_prior, outliers, search.notes(keep))


# ----------------------------------------------------------------------------- the test


@dataclass(frozen=True)
class _Test:
    threshold: float            # [m] floor
    false_rejection: float      # overall, split over n_points
    sigma_prior: float | None   # [m]
    n_points: int

    def __post_init__(self) -> None:
        if not (0.0 < self.false_rejection < 1.0 and self.threshold >= 0.0
                and (self.sigma_prior is None or self.sigma_prior > 0.0)):
            raise ValueError(f'need 0 < false_rejection < 1, threshold >= 0 [m] and '
                             f'sigma_prior > 0 [m] or None, got {self.false_rejection!r}, '
                             f'{self.threshold!r} and {self.sigma_prior!r}')

    def critical(self, dof: float) -> float:
        """Critical t^2 for a fit of the others with ``dof`` residual degrees of freedom."""
        level = self.false_rejection / self.n_points
        return _critical(level, math.inf if self.sigma_prior is not None else float(dof))

    def fails(self, error: Array, t2: Array, dof: float) -> Array:
        """Which tests fail: significant and beyond the floor (nan t2, untestable, passes)."""
        return (t2 > self.critical(dof)) & (error > self.threshold)


@lru_cache(maxsize=256)
def _critical(level: float, dof: float) -> float:
    """Upper ``level`` quantile of t^2: chi-square(3), or 3 F(3, dof) with estimated noise."""
    from scipy.stats import chi2, f     # here: importing scipy.stats takes 0.35 s
    if math.isinf(dof):
        return float(chi2.isf(level, 3))
    return float(3.0 * f.isf(level, 3, dof))


# ----------------------------------------------------------------------------- batched fits


@dataclass(frozen=True)
class _Fits:
    """Rigid fits of b subsets of the points (rows of a mask), to predict any point with."""

    R: Array        # (b, 3, 3)
    t: Array        # (b, 3) [m]
    rss: Array      # (b,) residual sum of squares [m^2]
    s2: Array       # (b,) noise variance per coordinate, estimated or prior [m^2]
    dof: Array      # (b,) residual degrees of freedom, 3 k - 6
    C: Array        # (b, 6, 6) pose covariance per unit noise
    spans: Array    # (b,) False where the subset is (nearly) collinear: nothing to predict


def _fit_subsets(pu: Array, pb: Array, masks: Array, sigma_prior: float | None) -> _Fits:
    """Kabsch fits of every subset ``masks[b]`` at once (points centred by the caller)."""
    W = masks.astype(float)
    k = W.sum(axis=1)
    cu, cb = (W @ pu) / k[:, None], (W @ pb) / k[:, None]
    Wu = W[:, :, None] * pu
    H = Wu.transpose(0, 2, 1) @ pb - k[:, None, None] * cu[:, :, None] * cb[:, None]
    U, _, Vt = np.linalg.svd(H)
    V = Vt.transpose(0, 2, 1).copy()
    V[:, :, 2] *= np.sign(np.linalg.det(V @ U.transpose(0, 2, 1)))[:, None]
    R = V @ U.transpose(0, 2, 1)
    t = cb - (R @ cu[:, :, None])[:, :, 0]
    q = pu @ R.transpose(0, 2, 1)
    rss = (W * ((q + t[:, None] - pb) ** 2).sum(axis=-1)).sum(axis=1)
    dof = 3.0 * k - 6.0
    s2 = (np.full_like(rss, sigma_prior ** 2) if sigma_prior is not None
          else np.maximum(rss / dof, _MIN_VARIANCE))
    spans = _spans(W, Wu, pu, pb, cu, cb, k)
    return _Fits(R, t, rss, s2, dof, _unit_covariance(W, q, k, spans), spans)


def _spans(W: Array, Wu: Array, pu: Array, pb: Array, cu: Array, cb: Array, k: Array
           ) -> Array:
    """(b,) True where neither weighted subset is collinear (s2 / s1 as in collinearity)."""
    Wb = W[:, :, None] * pb
    scatter = np.concatenate([
        Wu.transpose(0, 2, 1) @ pu - k[:, None, None] * cu[:, :, None] * cu[:, None],
        Wb.transpose(0, 2, 1) @ pb - k[:, None, None] * cb[:, :, None] * cb[:, None]])
    lam = np.linalg.eigvalsh(scatter)
    ok = np.sqrt(np.maximum(lam[:, 1], 0.0)) >= MIN_COLLINEARITY * np.sqrt(lam[:, 2])
    return ok[:len(k)] & ok[len(k):]


def _unit_covariance(W: Array, q: Array, k: Array, spans: Array) -> Array:
    """(b, 6, 6) (J^T J)^-1 of each subset, J rows [I, -[q]x]; identity where it does not span."""
    Wq = W[:, :, None] * q
    total = skew(Wq.sum(axis=1))
    qq = Wq.transpose(0, 2, 1) @ q
    JtJ = np.zeros((len(k), 6, 6))
    JtJ[:, :3, :3] = k[:, None, None] * _I3
    JtJ[:, :3, 3:] = -total
    JtJ[:, 3:, :3] = total
    JtJ[:, 3:, 3:] = np.trace(qq, axis1=1, axis2=2)[:, None, None] * _I3 - qq
    JtJ[~spans] = _I6
    return np.linalg.inv(JtJ)


def _predict(fits: _Fits, which: Array, points: Array, pu: Array, pb: Array
             ) -> tuple[Array, Array]:
    """|d| [m] and t^2 of ``points[i]`` against fit ``which[i]``; t^2 nan where none spans."""
    q = (fits.R[which] @ pu[points][:, :, None])[:, :, 0]
    d = pb[points] - q - fits.t[which]
    A = np.zeros((len(q), 3, 6))
    A[:, :, :3] = _I3
    A[:, :, 3:] = -skew(q)
    S = _I3 + A @ fits.C[which] @ A.transpose(0, 2, 1)
    t2 = (d * np.linalg.solve(S, d[:, :, None])[:, :, 0]).sum(axis=1) / fits.s2[which]
    return np.linalg.norm(d, axis=1), np.where(fits.spans[which], t2, np.nan)


# ----------------------------------------------------------------------------- the search


@dataclass(frozen=True)
class _Loo:
    """Each member of a set tested against the fit of the other members."""

    members: Array      # (m,) point indices
    fits: _Fits         # fits[r]: the set without members[r]
    error: Array        # (m,) prediction error norms [m]
    t2: Array           # (m,) studentized squared errors, nan where untestable
    fails: Array        # (m,) bool


@dataclass
class _Search:
    pu: Array           # (N, 3) centred [m]
    pb: Array           # (N, 3) centred [m]
    names: Names
    test: _Test
    _loos: dict[bytes, _Loo] = field(default_factory=dict)
    _fits: dict[bytes, _Fits] = field(default_factory=dict)

    def drop(self, keep: Array) -> tuple[Array, Failure | None]:
        """Drop the most significant failing point and refit, while any fails the test."""
        while True:
            loo = self.loo(keep)
            if not loo.fails.any():
                return keep, None
            worst = int(loo.members[np.argmax(np.where(loo.fails, loo.t2, -np.inf))])
            if keep.sum() <= MIN_INLIERS:
                return keep, self._too_many(keep, worst, loo)
            keep = keep.copy()
            keep[worst] = False

    def loo(self, keep: Array) -> _Loo:
        """Leave-one-out test of the members of ``keep`` (cached)."""
        key = keep.tobytes()
        if key not in self._loos:
            members = np.flatnonzero(keep)
            masks = np.repeat(keep[None], len(members), axis=0)
            masks[np.arange(len(members)), members] = False
            fits = _fit_subsets(self.pu, self.pb, masks, self.test.sigma_prior)
            error, t2 = _predict(fits, np.arange(len(members)), members, self.pu, self.pb)
            self._loos[key] = _Loo(members, fits, error, t2,
                                   self.test.fails(error, t2, float(fits.dof[0])))
        return self._loos[key]

    def fit(self, keep: Array) -> _Fits:
        """The fit of the points of ``keep`` (cached)."""
        key = keep.tobytes()
        if key not in self._fits:
            self._fits[key] = _fit_subsets(self.pu, self.pb, keep[None], self.test.sigma_prior)
        return self._fits[key]

    def against(self, keep: Array, points: Array) -> tuple[Array, Array, float]:
        """|d| [m] and t^2 of ``points`` against the fit of ``keep``, and its dof."""
        fit = self.fit(keep)
        error, t2 = _predict(fit, np.zeros(len(points), dtype=int), points, self.pu, self.pb)
        return error, t2, float(fit.dof[0])

    # -- ambiguity -------------------------------------------------------------------------

    def ambiguity(self, keep: Array) -> Failure | None:
        """Failure naming a rejected point and the inliers the data cannot tell it from."""
        for out in np.flatnonzero(~keep):
            rivals = self._rivals(keep, int(out))
            if rivals:
                named = ' or '.join(self.names[i] for i in sorted([int(out), *rivals]))
                return Failure(ErrorCode.DEGENERATE_POINTS, (
                    f'a gross error is present, but the layout cannot tell which of points '
                    f'{named} is wrong (dropping either leaves an equally good fit); re-touch '
                    'them, or lay out the markers so that no three are on a line'))
        return None

    def _rivals(self, keep: Array, out: int) -> list[int]:
        """Inliers m such that keep - m + out passes the test and fits as well as keep."""
        loo = self.loo(keep)
        error, t2 = _predict(loo.fits, np.arange(len(loo.members)),
                             np.full(len(loo.members), out), self.pu, self.pb)
        rivals = []
        for m in loo.members[~self.test.fails(error, t2, float(loo.fits.dof[0]))]:
            swapped = keep.copy()
            swapped[[m, out]] = [False, True]
            if self._as_good(keep, swapped) and not self.loo(swapped).fails.any():
                rivals.append(int(m))
        return rivals

    def _as_good(self, keep: Array, swapped: Array) -> bool:
        """True if ``swapped`` spans and its residual sum is within chance of ``keep``'s."""
        mine, theirs = self.fit(keep), self.fit(swapped)
        if not theirs.spans[0]:
            return False
        prior = self.test.sigma_prior is not None
        level = _critical(_AMBIGUITY_LEVEL, math.inf if prior else float(mine.dof[0]))
        return bool(theirs.rss[0] - mine.rss[0] <= level * mine.s2[0])

    # -- messages --------------------------------------------------------------------------

    def notes(self, keep: Array) -> str:
        """One note per rejected point: how far off the fit of the inliers, and the limit."""
        out = np.flatnonzero(~keep)
        if len(out) == 0:
            return ''
        error, t2, dof = self.against(keep, out)
        limit = math.sqrt(self.test.critical(dof))
        return _join(*(
            f'rejected {self.names[i]}: {e * 1e3:.3f} mm off the fit of the inliers, '
            f'{math.sqrt(v):.1f} standard deviations (limit {limit:.1f} for a '
            f'{self.test.false_rejection:.1%} false-rejection rate); re-touch it'
            for i, e, v in zip(out, error, t2)))

    def _too_many(self, keep: Array, worst: int, loo: _Loo) -> Failure:
        r = int(np.flatnonzero(loo.members == worst)[0])
        limit = math.sqrt(self.test.critical(float(loo.fits.dof[r])))
        rejected = ', '.join(self.names[i] for i in np.flatnonzero(~keep))
        return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
            f'too many gross errors: after rejecting {rejected}, {self.names[worst]} is still '
            f'{loo.error[r] * 1e3:.3f} mm off the fit of the other {keep.sum() - 1} points, '
            f'{math.sqrt(loo.t2[r]):.1f} standard deviations (limit {limit:.1f}), and at least '
            f'{MIN_INLIERS} points must remain; re-touch these points or touch more markers'))
