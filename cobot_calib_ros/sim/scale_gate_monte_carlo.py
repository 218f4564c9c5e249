"""Monte-Carlo of the plausibility gate on five_point_lsq fits, beside the OLD fixed 1 % rule.

Shared by test/core/user_frame/test_scale_gate.py and bench/bench_scale_gate.py. Layout
families of 5-8 points, each trial drawing a fresh layout, a random rigid pose and Gaussian
noise per coordinate on the base points: ``box`` uniform in an 8 cm cube (the user report: 6
points, 0.1 mm, scale 1.0156 refused), ``slab`` uniform in 8 x 8 x 2 cm (thin: the scale along
z is poorly determined), and ``plane`` robust_monte_carlo's close/small layouts (coplanar; M's
normal column is completed). Mistakes a user makes, each applied to one trial's data:

- ``base_mm`` / ``user_mm``: the base (user) points in millimetres, the others in metres;
- ``mirrored``: the user layout with its x axis negated (left-handed coordinates); on a coplanar
  layout a mirror is a half turn, so no point-based check can see it (``MIRROR_FAMILIES``);
- ``swapped``: two points measured in the wrong order;
- ``other_layout``: the user coordinates of another layout of the same family (wrong file;
  ``plane``: close for small and the reverse);
- ``stretched``: the user layout 3 % too large along a random axis (a wrongly scaled drawing).

A trial is refused when calibrate()'s gate, check_plausible with the node's defaults
(max_rms_error 1 mm, max_scale_error 1 %), refuses the fit; a failed fit (a degenerate draw) is
counted apart.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from cobot_calib_ros.sim.robust_monte_carlo import LAYOUTS as PLANE_LAYOUTS, random_pose

from cobot_calib_ros.core import user_frame as uf
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import apply

Array = np.ndarray
SPAN = 0.08               # [m] edge of the box and slab layouts
SLAB_HEIGHT = 0.02        # [m]
MAX_RMS_ERROR = 1e-3      # [m] config/user_frame_solver.yaml
MAX_SCALE_ERROR = 0.01    # config/user_frame_solver.yaml
STRETCH = 0.03
FAMILIES = ('box', 'slab', 'plane')
POINTS = (5, 6, 7, 8)
MIRROR_FAMILIES = ('box', 'slab')
MISTAKES = ('base_mm', 'user_mm', 'mirrored', 'swapped', 'other_layout', 'stretched')


@dataclass(frozen=True)
class Rates:
    """Outcome fractions of a case [0..1]."""

    trials: int
    refused: float        # IMPLAUSIBLE_FIT by the gate
    old_refused: float    # by the OLD rule (fixed 1 % scale, same residual limits)
    failed: float         # another failure (degenerate draw)


def layout(family: str, n: int, rng: np.random.Generator) -> Array:
    """(n, 3) user points [m] of one draw of ``family``."""
    if family == 'box':
        return rng.uniform(0.0, SPAN, (n, 3))
    if family == 'slab':
        return rng.uniform(0.0, 1.0, (n, 3)) * [SPAN, SPAN, SLAB_HEIGHT]
    if family == 'plane':
        return PLANE_LAYOUTS[f'{"close" if rng.random() < 0.5 else "small"}{n}'].copy()
    raise ValueError(f'unknown family {family!r}')


def draw(family: str, n: int, sigma: float, mistake: str, rng: np.random.Generator
         ) -> tuple[Array, Array]:
    """(p_user as the user gives it, p_base as measured) of one trial [m]."""
    p_user = layout(family, n, rng)
    p_base = apply(random_pose(rng), p_user) + rng.normal(0.0, sigma, p_user.shape)
    return MISTAKE[mistake](p_user, p_base, family, rng)


def _clean(pu: Array, pb: Array, family: str, rng: np.random.Generator) -> tuple[Array, Array]:
    return pu, pb


def _swapped(pu: Array, pb: Array, family: str, rng: np.random.Generator
             ) -> tuple[Array, Array]:
    i, j = rng.choice(len(pb), 2, replace=False)
    pb = pb.copy()
    pb[[i, j]] = pb[[j, i]]
    return pu, pb


def _stretched(pu: Array, pb: Array, family: str, rng: np.random.Generator
               ) -> tuple[Array, Array]:
    factor = np.ones(3)
    factor[rng.integers(3 if family != 'plane' else 2)] += STRETCH
    return pu * factor, pb


def _other_layout(pu: Array, family: str, rng: np.random.Generator) -> Array:
    if family != 'plane':
        return layout(family, len(pu), rng)
    close = PLANE_LAYOUTS[f'close{len(pu)}']
    return PLANE_LAYOUTS[f'small{len(pu)}'] if np.array_equal(pu, close) else close


MISTAKE: dict[str, Callable[[Array, Array, str, np.random.Generator], tuple[Array, Array]]] = {
    'clean': _clean,
    'base_mm': lambda pu, pb, family, rng: (pu, pb * 1e3),
    'user_mm': lambda pu, pb, family, rng: (pu * 1e3, pb),
    'mirrored': lambda pu, pb, family, rng: (pu * [-1.0, 1.0, 1.0], pb),
    'swapped': _swapped,
    'other_layout': lambda pu, pb, family, rng: (_other_layout(pu, family, rng), pb),
    'stretched': _stretched,
}


def old_rule_refuses(fit: uf.FrameFit) -> bool:
    """OLD gate, for comparison only: |scale - 1| > 1 % of the fit, or its residual limits."""
    return bool(np.abs(fit.scale - 1.0).max() > MAX_SCALE_ERROR) or fit.rms > MAX_RMS_ERROR or (
        fit.max_residual > uf.MAX_RESIDUAL_FACTOR * MAX_RMS_ERROR)


def run_case(family: str, n: int, sigma: float, mistake: str, trials: int, seed: int
             ) -> Rates:
    """Rates of the gate over ``trials`` draws of ``family`` with ``n`` points.

    The gate is calibrate()'s: check_plausible on the method's fit, with the node's limits.
    """
    rng = np.random.default_rng(seed)
    refused = old_refused = failed = 0
    for _ in range(trials):
        fit = uf.fit_five_point_lsq(*draw(family, n, sigma, mistake, rng))
        if not fit:
            failed += 1
            continue
        problem = uf.check_plausible(fit, MAX_RMS_ERROR, MAX_SCALE_ERROR)
        refused += problem is not None and problem.code == ErrorCode.IMPLAUSIBLE_FIT
        old_refused += old_rule_refuses(fit)
    return Rates(trials, refused / trials, old_refused / trials, failed / trials)


def pooled(family: str, sigma: float, mistake: str, trials: int, seed: int) -> Rates:
    """Rates over ``trials`` draws for each of 5-8 points, pooled."""
    cases = [run_case(family, n, sigma, mistake, trials, seed + n) for n in POINTS]
    total = trials * len(cases)
    return Rates(total, *(sum(getattr(c, name) * c.trials for c in cases) / total
                          for name in ('refused', 'old_refused', 'failed')))
