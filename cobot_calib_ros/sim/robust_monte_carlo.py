"""Monte-Carlo of the robust method's outlier rule, beside the OLD fixed-limit rule it replaced.

Shared by test/core/user_frame/test_robust_sim.py and bench/bench_robust_fit.py. Rigid layouts
of 5-8 points (z = 0.02 m): ``close`` is the first paper's "close" layout (P1-P5) extended with the side
midpoints P6-P8; ``small`` the same shape in 9 x 6 cm; ``corner`` a 9 x 6 cm layout of a tight
cluster (2 x 2 cm) and one far corner, whose prediction from the others has a large leverage
(the user report: the OLD rule rejected that good corner in about a fifth of trials). Each
trial draws a random rigid pose and Gaussian noise per coordinate on the base points, and
optionally one outlier of a given size in a random direction on a random point. A rule maps
(p_user, p_base) to the rejected indices, or None when it refuses (e.g. "cannot tell which
point is wrong").
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable

import numpy as np

from cobot_calib_ros.core import user_frame as uf
from cobot_calib_ros.core.frames import Rotation
from cobot_calib_ros.core.frames import apply, make_transform

Array = np.ndarray
Rule = Callable[[Array, Array], 'tuple[int, ...] | None']

_CLOSE = [(0.15, 0.10), (0.35, 0.10), (0.35, 0.25), (0.15, 0.25), (0.25, 0.175),   # paper
          (0.25, 0.10), (0.35, 0.175), (0.25, 0.25)]                              # midpoints
_SMALL = [(0.15 + 0.45 * (x - 0.15), 0.10 + 0.4 * (y - 0.10)) for x, y in _CLOSE]  # 9 x 6 cm
_CLUSTER = [(0.0, 0.0), (0.01, 0.0), (0.0, 0.01), (0.02, 0.0), (0.01, 0.01), (0.02, 0.01),
            (0.0, 0.02)]
Z = 0.02  # [m] marker height in the user frame
LAYOUTS = {f'{name}{n}': np.array([[x, y, Z] for x, y in points(n)])
           for name, points in (('close', lambda n: _CLOSE[:n]), ('small', lambda n: _SMALL[:n]),
                                ('corner', lambda n: [*_CLUSTER[:n - 1], (0.09, 0.06)]))
           for n in (5, 6, 7, 8)}


@dataclass(frozen=True)
class Rates:
    """Outcome fractions of a case [0..1]."""

    trials: int
    named: float      # exactly the bad point rejected (clean data: nothing rejected)
    wrong: float      # a good point rejected (alone or with the bad one)
    refused: float    # no fit (ambiguous / too many outliers)


def random_pose(rng: np.random.Generator) -> Array:
    """A uniformly random rotation and a translation within +-0.5 m per axis."""
    R = Rotation.random(random_state=rng).as_matrix()
    return make_transform(R, rng.uniform(-0.5, 0.5, 3))


def draw(layout: Array, sigma: float, outlier: float, rng: np.random.Generator
         ) -> tuple[Array, int | None]:
    """Base points of one trial, and the index of the bad point (None without outlier)."""
    p_base = apply(random_pose(rng), layout) + rng.normal(0.0, sigma, layout.shape)
    if outlier <= 0.0:
        return p_base, None
    index = int(rng.integers(len(layout)))
    direction = rng.normal(size=3)
    p_base[index] += outlier * direction / np.linalg.norm(direction)
    return p_base, index


def run_case(rule: Rule, layout: Array, sigma: float, outlier: float, trials: int,
             seed: int) -> Rates:
    """Rates of ``rule`` over ``trials`` draws (noise ``sigma`` [m], one ``outlier`` [m])."""
    rng = np.random.default_rng(seed)
    named = wrong = refused = 0
    for _ in range(trials):
        p_base, bad = draw(layout, sigma, outlier, rng)
        rejected = rule(layout, p_base)
        if rejected is None:
            refused += 1
            continue
        expected = () if bad is None else (bad,)
        named += rejected == expected
        wrong += any(i != bad for i in rejected)
    return Rates(trials, named / trials, wrong / trials, refused / trials)


def new_rule(p_user: Array, p_base: Array) -> tuple[int, ...] | None:
    """The package's robust method, statistical test only (floor 0)."""
    fit = uf.fit_robust(p_user, p_base, threshold=0.0)
    return fit.outliers if fit else None


# ------------------------------------------------------------------------------------------
# OLD RULE, for comparison only: the robust method before the studentized test replaced it
# (fixed 0.5 mm limit, or 5 median-based sigmas if larger). Not in the package.
# ------------------------------------------------------------------------------------------

OLD_THRESHOLD = 5e-4      # [m]
OLD_K_SIGMA = 5.0
_CHI3_MEDIAN = 1.5382


def old_rule(p_user: Array, p_base: Array) -> tuple[int, ...] | None:
    """The OLD robust method's rejected indices, None when it refused as ambiguous."""
    outliers, rivals = old_rule_detail(p_user, p_base)
    return None if rivals else outliers


def old_rule_detail(pu: Array, pb: Array) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(rejected, named in the OLD "cannot tell which of points ..." refusal, or ())."""
    if len(pu) < 4:
        return (), ()
    keep = _old_reinstate(pu, pb, _old_drop_outliers(pu, pb))
    return tuple(int(i) for i in np.flatnonzero(~keep)), _old_ambiguity(pu, pb, keep)


def _old_kabsch(pu: Array, pb: Array) -> Array:
    cu, cb = pu.mean(axis=0), pb.mean(axis=0)
    U, _, Vt = np.linalg.svd((pu - cu).T @ (pb - cb))
    R = Vt.T @ np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))]) @ U.T
    return make_transform(R, cb - R @ cu)


def _old_check(pu: Array, pb: Array, keep: Array) -> tuple[Array, float]:
    r = np.linalg.norm(apply(_old_kabsch(pu[keep], pb[keep]), pu) - pb, axis=1)
    n = int(keep.sum())
    sigma = float(np.median(r[keep])) / _CHI3_MEDIAN * math.sqrt(n / max(n - 2, 1))
    return r, max(OLD_THRESHOLD, OLD_K_SIGMA * sigma)


def _old_spans(pu: Array, pb: Array) -> bool:
    return min(uf.collinearity(pu), uf.collinearity(pb)) >= 1e-3


def _old_drop_outliers(pu: Array, pb: Array) -> Array:
    keep = np.ones(len(pu), dtype=bool)
    while keep.sum() >= 4:
        worst = _old_worst_point(pu, pb, keep)
        if worst is None:
            break
        keep[worst] = False
    return keep


def _old_worst_point(pu: Array, pb: Array, keep: Array) -> int | None:
    worst, error, limit = None, 0.0, math.inf
    for i in np.flatnonzero(keep):
        rest = keep.copy()
        rest[i] = False
        if _old_spans(pu[rest], pb[rest]):
            r, rest_limit = _old_check(pu, pb, rest)
            if r[i] > error:
                worst, error, limit = int(i), float(r[i]), rest_limit
    return worst if error > limit else None


def _old_reinstate(pu: Array, pb: Array, keep: Array) -> Array:
    if keep.all():
        return keep
    r, limit = _old_check(pu, pb, keep)
    return keep | (r <= limit)


def _old_ambiguity(pu: Array, pb: Array, keep: Array) -> tuple[int, ...]:
    _, limit = _old_check(pu, pb, keep)
    for out in np.flatnonzero(~keep):
        rivals = []
        for inlier in np.flatnonzero(keep):
            trial = keep.copy()
            trial[[out, inlier]] = [True, False]
            if _old_consistent(pu, pb, trial, limit):
                rivals.append(int(inlier))
        if rivals:
            return (int(out), *rivals)
    return ()


def _old_consistent(pu: Array, pb: Array, trial: Array, limit: float) -> bool:
    if not _old_spans(pu[trial], pb[trial]):
        return False
    r, _ = _old_check(pu, pb, trial)
    if r[trial].max() > limit:
        return False
    for m in np.flatnonzero(trial):
        rest = trial.copy()
        rest[m] = False
        if _old_spans(pu[rest], pb[rest]) and _old_check(pu, pb, rest)[0][m] > limit:
            return False
    return True
