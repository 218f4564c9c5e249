"""Monte-Carlo of the robust method's outlier test, beside the OLD fixed-limit rule
(sim.robust_monte_carlo).

0.1 mm of Gaussian noise per coordinate, a random rigid pose per trial, seeded generators (the
figures, and so the assertions, are deterministic). The table is printed even without -s; the
full table (2, 3, 4, 5 mm, 0.036 mm noise too) is bench/bench_robust_fit.py's.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.sim import robust_monte_carlo as rs
from cobot_calib_ros.core import user_frame as uf

SIGMA = 1e-4          # [m] noise per coordinate
OUTLIER = 3e-3        # [m]
CLEAN_TRIALS = 2000
DETECT_TRIALS = 500
OLD_TRIALS = 100      # the OLD rule is slow: run where it is asserted or telling (bench: all)
CLEAN = [f'{family}{n}' for family in ('close', 'small') for n in (5, 6, 7, 8)] + ['corner8']
DETECT = ['close5', 'close6', 'close7', 'close8', 'small6', 'small7', 'small8', 'corner8']
OLD_CLEAN = ['small5', 'corner8']
OLD_DETECT = ['close5', 'small6', 'corner8']
Table = dict[str, tuple[rs.Rates, 'rs.Rates | None']]


def rates(rule: rs.Rule, names: list[str], outlier: float, trials: int, seed: int
          ) -> dict[str, rs.Rates]:
    return {name: rs.run_case(rule, rs.LAYOUTS[name], SIGMA, outlier, trials, seed + i)
            for i, name in enumerate(names)}


@pytest.fixture(scope='module')
def clean() -> Table:
    new = rates(rs.new_rule, CLEAN, 0.0, CLEAN_TRIALS, 1000)
    old = rates(rs.old_rule, OLD_CLEAN, 0.0, OLD_TRIALS, 2000)
    return {name: (new[name], old.get(name)) for name in CLEAN}


@pytest.fixture(scope='module')
def detection() -> Table:
    new = rates(rs.new_rule, DETECT, OUTLIER, DETECT_TRIALS, 3000)
    old = rates(rs.old_rule, OLD_DETECT, OUTLIER, OLD_TRIALS, 4000)
    return {name: (new[name], old.get(name)) for name in DETECT}


def show(title: str, table: Table, capsys: pytest.CaptureFixture) -> None:
    with capsys.disabled():
        trials = next(iter(table.values()))[0].trials
        print(f'\n{title} (0.1 mm noise; new: {trials} trials, OLD: {OLD_TRIALS})')
        print(f'{"layout":8}  {"new named":>9} {"wrong":>6} {"refused":>7}   '
              f'{"OLD named":>9} {"wrong":>6} {"refused":>7}')
        for name, (new, old) in table.items():
            olds = (f'{old.named:9.2%} {old.wrong:6.2%} {old.refused:7.2%}' if old
                    else f'{"-":>9} {"-":>6} {"-":>7}')
            print(f'{name:8}  {new.named:9.2%} {new.wrong:6.2%} {new.refused:7.2%}   {olds}')


def test_clean_data_loses_a_good_point_in_under_one_percent(
        clean: Table, capsys: pytest.CaptureFixture) -> None:
    """Design rate 0.5 %; measured 0.25-0.6 % (2000 trials each), small layouts included."""
    show('clean data: named = nothing rejected', clean, capsys)
    for name, (new, _) in clean.items():
        assert new.wrong + new.refused < 0.01, (name, new)


def test_the_old_rule_lost_the_good_corner_of_a_high_leverage_layout(clean: Table) -> None:
    """The user report: 9 x 6 cm, 8 points, 0.1 mm noise: the OLD fixed 0.5 mm limit rejected
    the good corner in about a fifth of trials (measured 24 % + 30 % refused), the new test
    accounts for its leverage."""
    new, old = clean['corner8']
    assert old.wrong > 0.15 and old.named < 0.6
    assert new.wrong + new.refused < 0.01


def test_a_3mm_outlier_is_named(detection: Table, capsys: pytest.CaptureFixture) -> None:
    """Measured: 98.4 % on close5 (the rest refused: true ambiguities of a 5-point layout, e.g.
    a corner's height), 99.0-99.8 % with 6-8 points; the OLD rule: 93 %, 88 % on small6 (11 %
    refused), 53 % on corner8."""
    show(f'one {OUTLIER * 1e3:g} mm outlier: named = exactly it rejected', detection, capsys)
    for name, (new, _) in detection.items():
        assert new.named > (0.97 if len(rs.LAYOUTS[name]) >= 6 else 0.95), (name, new)
        assert new.wrong < 0.01, (name, new)
    assert detection['corner8'][1].named < 0.7


def test_a_good_point_named_with_the_outlier_by_the_old_rule_is_kept() -> None:
    """The user report: 6 points, 4.45 mm of error on one, refused by the OLD rule as "cannot
    tell which of points 0 or 5 is wrong", two good points. Reproduced on the corner6 layout."""
    layout = rs.LAYOUTS['corner6']
    for seed, bad in ((50, 1), (99, 1)):
        p_base, drawn = rs.draw(layout, SIGMA, 4.45e-3, np.random.default_rng(seed))
        assert drawn == bad
        _, named = rs.old_rule_detail(layout, p_base)
        assert sorted(named) == [0, 5] and bad not in named
        fit = uf.fit_robust(layout, p_base)
        assert fit and fit.outliers == (bad,), fit.message
        assert f'rejected P{bad + 1}: 4.' in fit.message
