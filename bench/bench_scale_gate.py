"""Plausibility gate of five_point_lsq: clean data refused and mistakes detected, new vs OLD.

Monte-Carlo of cobot_calib_ros/sim/scale_gate_monte_carlo.py (layout families box, slab and
plane of 5-8 points, a fresh layout and rigid pose per trial, 0.1 mm of Gaussian noise per coordinate; the
OLD fixed 1 % scale rule kept there for comparison only). Figures, per rule (new | old) and
family:

- ``scale_gate_<rule>_<family>_clean_refused_percent`` [%]: clean data refused (goal < 1 %);
- ``scale_gate_<rule>_<family>_<mistake>_refused_percent`` [%]: a mistake detected (base or
  user points in mm, a mirrored layout, two points swapped, another layout, a 3 % stretch).

Pure computation, no ROS. Seeded (numpy default_rng): the figures repeat. Trials per point count:
CLEAN_TRIALS and MISTAKE_TRIALS, or ``--trials N`` for both.
"""
from __future__ import annotations

import sys

import benchlib
from benchlib import Figures

from cobot_calib_ros.sim import scale_gate_monte_carlo as ss

CLEAN_TRIALS = 1000
MISTAKE_TRIALS = 100
SIGMA = 1e-4              # [m] per coordinate


def case_figures(family: str, mistake: str, trials: int, seed: int) -> Figures:
    rates = ss.pooled(family, SIGMA, mistake, trials, seed)
    return {f'scale_gate_{rule}_{family}_{mistake}_refused_percent': (100.0 * value, '%')
            for rule, value in (('new', rates.refused), ('old', rates.old_refused))}


def run(clean_trials: int = CLEAN_TRIALS, mistake_trials: int = MISTAKE_TRIALS) -> Figures:
    figures: Figures = {}
    for i, family in enumerate(ss.FAMILIES):
        figures.update(case_figures(family, 'clean', clean_trials, 100 * i))
        for j, mistake in enumerate(ss.MISTAKES):
            if mistake != 'mirrored' or family in ss.MIRROR_FAMILIES:
                figures.update(case_figures(family, mistake, mistake_trials, 1000 + 10 * j))
    return figures


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == '--trials':
        return benchlib.main(lambda: run(int(argv[1]), int(argv[1])))
    return benchlib.main(run)


if __name__ == '__main__':
    raise SystemExit(main(sys.argv[1:]))
