"""Outlier test of the robust user-frame fit: detection and false-rejection rates, new vs OLD.

Monte-Carlo of cobot_calib_ros/sim/robust_monte_carlo.py (layouts, trial draws, and the OLD fixed
0.5 mm rule kept there for comparison only): layouts close5-8 (the first paper's "close" layout
and side midpoints), small5-8 (the same in 9 x 6 cm) and corner8 (9 x 6 cm: a cluster and one
far corner), 0.1 and 0.036 mm of Gaussian noise per coordinate, a random rigid pose per trial;
one 2, 3, 4 or 5 mm outlier in a random direction on a random point, or none. Figures, per
rule (new | old), layout and noise:

- ``robust_<rule>_<layout>_<noise>um_clean_false_rejection_percent`` [%]: clean data, a good point
  rejected or the fit refused;
- ``robust_<rule>_<layout>_<noise>um_<size>mm_named_percent`` [%]: exactly the bad point rejected.

Pure computation, no ROS. Seeded (numpy default_rng): the figures repeat. Trials: NEW_TRIALS and
OLD_TRIALS (the OLD rule is slower), or ``--trials N`` for both.
"""
from __future__ import annotations

import sys

import benchlib
from benchlib import Figures

from cobot_calib_ros.sim import robust_monte_carlo as rs

NEW_TRIALS = 2000
OLD_TRIALS = 300
LAYOUTS = [f'{family}{n}' for family in ('close', 'small') for n in (5, 6, 7, 8)] + ['corner8']
NOISES = (1e-4, 3.6e-5)             # [m] per coordinate
OUTLIERS = (2e-3, 3e-3, 4e-3, 5e-3)  # [m]
RULES = {'new': rs.new_rule, 'old': rs.old_rule}


def case_figures(rule: str, layout: str, sigma: float, trials: int, seed: int) -> Figures:
    """The clean false-rejection rate and the detection rate of each outlier size [%]."""
    prefix = f'robust_{rule}_{layout}_{sigma * 1e6:g}um'
    clean = rs.run_case(RULES[rule], rs.LAYOUTS[layout], sigma, 0.0, trials, seed)
    figures = {f'{prefix}_clean_false_rejection_percent': (100.0 * (1.0 - clean.named), '%')}
    for k, size in enumerate(OUTLIERS, start=1):
        rates = rs.run_case(RULES[rule], rs.LAYOUTS[layout], sigma, size, trials, seed + k)
        figures[f'{prefix}_{size * 1e3:g}mm_named_percent'] = (100.0 * rates.named, '%')
    return figures


def run(new_trials: int = NEW_TRIALS, old_trials: int = OLD_TRIALS) -> Figures:
    figures: Figures = {}
    for i, layout in enumerate(LAYOUTS):
        for j, sigma in enumerate(NOISES):
            seed = 100 * (len(NOISES) * i + j)
            for rule, trials in (('new', new_trials), ('old', old_trials)):
                figures.update(case_figures(rule, layout, sigma, trials, seed))
    return figures


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == '--trials':
        return benchlib.main(lambda: run(int(argv[1]), int(argv[1])))
    return benchlib.main(run)


if __name__ == '__main__':
    raise SystemExit(main(sys.argv[1:]))
