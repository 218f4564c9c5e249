"""Algorithm 1 (redundant parameters) on iiwa7, in the paper's setup and with an eccentric tool."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics.identification import (
    base_motion_columns, default_candidates, find_redundant, ParameterSet,
    uniform_configurations)
from cobot_calib_ros.core.kinematics.model import iiwa7
from cobot_calib_ros.core.kinematics.robots import model_by_name

MODEL = iiwa7()
ECCENTRIC_TOOL = np.array([0.030, -0.010, 0.060])  # [m]
# Flange (tool on the z7 axis) position-only: the flange point's position in frame 6 is one
# 3-vector, spanned by these six parameters -> 3 of them are redundant.
WRIST_GROUP = {'theta_6', 'd_6', 'alpha_7', 'a_7', 'theta_7', 'd_7'}
MDH_CANDIDATES = MODEL.parameter_names[4:]  # 28 minus the first row's 4


def _report(result) -> None:
    for d in result.dropped:
        print(f'  dropped {d.name:8s} cond {d.condition_before:.4g} -> {d.condition_after:.4g}')
    print(f'  rank {result.rank}, kept {len(result.kept)}, cond {result.condition_number:.4g}')


def _kept_condition(model, q, tool, kept) -> tuple[int, float]:
    _, J = ParameterSet(model, kept).positions_and_jacobian(None, tool, q)
    J = J.reshape(-1, len(kept))
    return int(np.linalg.matrix_rank(J)), float(np.linalg.cond(J))


def test_paper_setup_keeps_21_parameters():
    """29 uniform configurations, tool at the flange, the 24 MDH parameters of rows 2-7.

    The paper finds d_6, a_6 (our a_7, row 7's a_{i-1}) and theta_7 redundant, 21 kept. Algorithm 1
    gives rank 21 and 21 kept here too, and with seed 0 on this machine exactly the paper's three
    (theta_7, d_6, a_7; conditions 4.1e16 -> 1.9e16 -> 1.8e16 -> 26.05). But the three redundant
    directions live in the wrist group {theta_6, d_6, alpha_7, a_7, theta_7}: with the tool on
    the z7 axis, theta_7 does nothing and the flange point in frame 6 is one 3-vector. While the
    matrix is still rank deficient the compared condition numbers are ~1e16, rounding noise
    (d_6's 1.7518e16 against alpha_7's 1.7555e16 at step 2), so which members go changes with
    the configurations (seeds 1-7 drop e.g. alpha_7 or theta_6) and could change with the BLAS.
    Asserted: what does not depend on rounding. Only the last removal has a meaningful
    condition number.
    """
    for seed in range(6):
        q = uniform_configurations(MODEL, 29, seed)
        result = find_redundant(MODEL, q, np.zeros(3), MDH_CANDIDATES)
        print(f'seed {seed}:')
        _report(result)
        names = {d.name for d in result.dropped}
        assert result.rank == 21 and len(result.kept) == 21 and len(names) == 3
        assert 'theta_7' in names  # an exactly zero column
        assert names <= WRIST_GROUP - {'d_7'}
        assert set(MDH_CANDIDATES) - WRIST_GROUP <= set(result.kept)
        assert all(d.condition_after > 1e12 for d in result.dropped[:-1])
        assert result.dropped[-1].condition_after == result.condition_number < 50.0
        assert _kept_condition(MODEL, q, np.zeros(3), result.kept) == (
            21, pytest.approx(result.condition_number, rel=1e-9))


def test_wrist_group_spans_three_directions():
    """The explanation above, checked: the wrist group's columns have rank 3 with the tool on
    the flange axis, and 5 (theta_7 starts to act) with an eccentric tool."""
    q = uniform_configurations(MODEL, 29, 0)
    group = tuple(sorted(WRIST_GROUP))
    assert _kept_condition(MODEL, q, np.zeros(3), group)[0] == 3
    assert _kept_condition(MODEL, q, ECCENTRIC_TOOL, group)[0] == 6


def test_eccentric_tool_with_tool_candidates():
    """The coupling's setup: tool centre off the flange axis, tool_x/y/z among the candidates.

    The eccentric tool makes the wrist orientation visible: the wrist group is no longer
    redundant. Two redundancies remain: theta_7 turns the tool about z7, as a rotation of
    (tool_x, tool_y) would; d_7 and tool_z are the same translation along z7 (identical
    columns). Rank 25 of 27; which member of each pair goes is again rounding (seed 0: theta_7,
    d_7; cond 72.6).
    """
    for seed in range(4):
        q = uniform_configurations(MODEL, 29, seed)
        result = find_redundant(MODEL, q, ECCENTRIC_TOOL, default_candidates(MODEL))
        print(f'seed {seed}:')
        _report(result)
        names = [d.name for d in result.dropped]
        assert result.rank == 25 and len(result.kept) == 25 and len(names) == 2
        assert len({'theta_7', 'tool_x', 'tool_y'} & set(names)) == 1
        assert len({'d_7', 'tool_z'} & set(names)) == 1
        assert result.condition_number < 500.0


def test_excluded_parameters_are_listed_first_with_their_reason():
    q = uniform_configurations(MODEL, 29, 0)
    base_row = MODEL.parameter_names[:4]
    reason = 'tied to the world frame'
    plain = find_redundant(MODEL, q, np.zeros(3), MDH_CANDIDATES)
    result = find_redundant(MODEL, q, np.zeros(3), MDH_CANDIDATES,
                            excluded={n: reason for n in base_row})
    assert [d.name for d in result.dropped[:4]] == list(base_row)
    assert all(d.reason == reason for d in result.dropped[:4])
    assert result.kept == plain.kept and result.rank == plain.rank
    # theta_1 is the same column as q1's: the full Jacobian is rank deficient with it
    assert all(np.isfinite(d.condition_before) for d in result.dropped[:4])
    assert result.dropped[3].condition_after == pytest.approx(
        np.linalg.cond(ParameterSet(MODEL, MDH_CANDIDATES).positions_and_jacobian(
            None, np.zeros(3), q)[1].reshape(-1, 24)))


def test_uniform_configurations_and_errors():
    q = uniform_configurations(MODEL, 29, 3)
    assert q.shape == (29, 7)
    assert np.all(q >= MODEL.lower) and np.all(q <= MODEL.upper)
    assert np.array_equal(q, uniform_configurations(MODEL, 29, 3))
    assert np.ptp(q, axis=0).min() > 0.5 * np.min(MODEL.upper - MODEL.lower)
    with pytest.raises(ValueError, match='unknown parameter names'):
        find_redundant(MODEL, q, np.zeros(3), ('d_3', 'd_33'))
    with pytest.raises(ValueError, match='finite'):
        find_redundant(MODEL, np.full((3, 7), np.nan), np.zeros(3), ('d_3',))


def test_sawyer_origin_model_needs_a_rank_tolerance():
    """Origin (URDF) models have 6 parameters per joint, so much more redundancy (rank 26 of 39
    here). The Sawyer URDF's rounded pi/2 (1.57079632679) leaves one near-redundancy at a
    singular value 8.5e-13 of the largest, above numpy's default rank threshold: Algorithm 1
    as published then keeps a set conditioned ~1e12; rank_rtol=1e-10 removes it."""
    model = model_by_name('sawyer')
    q = uniform_configurations(model, 40, 0)
    candidates = default_candidates(model)
    assert len(candidates) == 6 * 6 + 3
    published = find_redundant(model, q, ECCENTRIC_TOOL, candidates)
    assert published.rank == 27 and published.condition_number > 1e11
    result = find_redundant(model, q, ECCENTRIC_TOOL, candidates, rank_rtol=1e-10)
    _report(result)
    assert result.rank == len(result.kept) == 26
    assert result.condition_number < 1e3


def test_base_frame_option_drops_parameters_equivalent_to_moving_the_base():
    """identify() leaves a rigid base motion free (relative data cannot see it, the absolute
    objective fits T_world_base). Sawyer's origin rows: two of the parameters Algorithm 1 keeps
    are such motions (the Jacobian with the 6 base columns loses 2 in rank); base_frame=True
    drops them. iiwa7 MDH: the excluded first row already covers it, same count either way."""
    for name, kept_with_base in (('sawyer', 24), ('iiwa7', 25)):
        model = model_by_name(name)
        q = uniform_configurations(model, 40, 0)
        ranks = {}
        for base_frame in (False, True):
            result = find_redundant(model, q, ECCENTRIC_TOOL, default_candidates(model),
                                    rank_rtol=1e-10, base_frame=base_frame)
            p, J = ParameterSet(model, result.kept).positions_and_jacobian(
                None, ECCENTRIC_TOOL, q)
            with_base = np.hstack([J.reshape(-1, len(result.kept)), base_motion_columns(p)])
            ranks[base_frame] = (len(result.kept),
                                 int(np.linalg.matrix_rank(with_base, rtol=1e-10)))
            assert result.rank == len(result.kept)
        print(name, ranks)
        assert ranks[True] == (kept_with_base, kept_with_base + 6)
        if name == 'sawyer':
            assert ranks[False] == (26, 26 + 4)
        else:
            assert ranks[False] == ranks[True]


def test_base_motion_columns_are_the_first_order_motion():
    p = np.random.default_rng(0).normal(size=(5, 3))
    motion = np.array([1e-7, -2e-7, 3e-7, 2e-7, -1e-7, 3e-7])  # [m, rad]
    moved = frames.apply(frames.from_vector(motion), p)
    assert (moved - p).ravel() == pytest.approx(base_motion_columns(p) @ motion, abs=1e-13)
