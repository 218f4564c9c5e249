"""Repeatability after the paper's eqs (9)-(15) and ISO 9283 RP_l, on hand-computed numbers."""
from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
import numpy as np
import pytest

from cobot_calib_ros.core.repeatability import (
    complete_cycles, correct_distance, deviations, iso9283_rp_3d, iso9283_rp_from_axes,
    overall_rp, point_statistics, probe_offset, range_correction)

MM = 1e-3  # [m]
TOL = 1e-12  # [m]

# Two points x five cycles, probe readings in mm.
# P1: 1.06 1.02 1.08 1.03 1.06 ; P2 never moves: 1.50 five times.
D_MM = np.array([[1.06, 1.02, 1.08, 1.03, 1.06],
                 [1.50, 1.50, 1.50, 1.50, 1.50]])


def test_hand_computed_two_points_five_cycles():
    # P1, eq (9):  d-bar = (1.06 + 1.02 + 1.08 + 1.03 + 1.06) / 5 = 5.25 / 5 = 1.05
    #     eq (10): D = |0.01|, |-0.03|, |0.03|, |-0.02|, |0.01| = 0.01 0.03 0.03 0.02 0.01
    #     eq (11): D-bar = 0.10 / 5 = 0.02
    #     eq (12): D - D-bar = -0.01 0.01 0.01 0 -0.01, squares sum to 4 * 0.0001 = 0.0004,
    #              / (n - 1 = 4) = 0.0001, sigma = 0.01
    #     eq (13): RP = 0.02 + 3 * 0.01 = 0.05
    # P2: d-bar = 1.50, every D = 0, D-bar = 0, sigma = 0, RP = 0 (perfectly repeatable)
    # eq (14): RP_all = (0.05 + 0) / 2 = 0.025            (all values in mm)
    d = D_MM * MM
    np.testing.assert_allclose(deviations(d), np.array(
        [[0.01, 0.03, 0.03, 0.02, 0.01], [0.0, 0.0, 0.0, 0.0, 0.0]]) * MM, atol=TOL)
    stats = point_statistics(d)
    assert stats
    assert stats.cycles == 5
    np.testing.assert_allclose(stats.mean_distance, [1.05 * MM, 1.50 * MM], atol=TOL)
    np.testing.assert_allclose(stats.mean_deviation, [0.02 * MM, 0.0], atol=TOL)
    np.testing.assert_allclose(stats.sigma, [0.01 * MM, 0.0], atol=TOL)
    np.testing.assert_allclose(stats.rp, [0.05 * MM, 0.0], atol=TOL)
    assert stats.rp_all == pytest.approx(0.025 * MM, abs=TOL)


def test_hand_computed_irrational_sigma():
    # d = 1 2 3 4 5 mm: d-bar = 15 / 5 = 3; D = 2 1 0 1 2; D-bar = 6 / 5 = 1.2;
    # D - D-bar = 0.8 -0.2 -1.2 -0.2 0.8, squares 0.64 0.04 1.44 0.04 0.64 sum to 2.8;
    # sigma = sqrt(2.8 / 4) = sqrt(0.7) = 0.8366600265; RP = 1.2 + 3 sqrt(0.7) = 3.7099800796
    stats = point_statistics([[1.0 * MM, 2.0 * MM, 3.0 * MM, 4.0 * MM, 5.0 * MM]])
    assert stats.mean_deviation[0] == pytest.approx(1.2 * MM, abs=TOL)
    assert stats.sigma[0] == pytest.approx(0.8366600265 * MM, abs=TOL)
    assert stats.rp[0] == pytest.approx(3.7099800796 * MM, abs=TOL)
    assert stats.rp_all == pytest.approx(3.7099800796 * MM, abs=TOL)


def test_running_statistics_after_two_cycles_by_hand():
    # First two cycles of P1: 1.06 1.02 -> d-bar 1.04, D = 0.02 0.02, D-bar 0.02, sigma 0
    # (two deviations from their own mean are always equal), RP = 0.02; P2: RP = 0;
    # RP_all = 0.01 mm. Cycle 3 is under way: only P1 has been measured.
    d = np.full((2, 5), math.nan)
    d[:, :2] = D_MM[:, :2] * MM
    d[0, 2] = D_MM[0, 2] * MM
    stats = point_statistics(d)
    assert stats.cycles == 2
    np.testing.assert_allclose(stats.mean_distance, [1.04 * MM, 1.50 * MM], atol=TOL)
    np.testing.assert_allclose(stats.sigma, [0.0, 0.0], atol=TOL)
    np.testing.assert_allclose(stats.rp, [0.02 * MM, 0.0], atol=TOL)
    assert stats.rp_all == pytest.approx(0.01 * MM, abs=TOL)


def test_one_cycle_has_no_sigma():
    d = np.full((2, 5), math.nan)
    d[:, 0] = [1.0 * MM, 2.0 * MM]
    stats = point_statistics(d)
    assert not stats
    assert stats.cycles == 1
    np.testing.assert_allclose(stats.mean_distance, [1.0 * MM, 2.0 * MM])
    np.testing.assert_allclose(stats.mean_deviation, [0.0, 0.0])
    assert np.isnan(stats.sigma).all() and np.isnan(stats.rp).all()
    assert math.isnan(stats.rp_all)


def test_no_cycle_yet():
    stats = point_statistics(np.full((3, 4), math.nan))
    assert not stats
    assert stats.cycles == 0
    assert np.isnan(stats.mean_distance).all() and math.isnan(stats.rp_all)


def test_a_cycle_with_a_lost_measurement_is_left_out_as_a_whole():
    d = D_MM * MM
    holed = d.copy()
    holed[1, 2] = math.nan
    np.testing.assert_array_equal(complete_cycles(holed), [True, True, False, True, True])
    expected = point_statistics(np.delete(d, 2, axis=1))
    got = point_statistics(holed)
    assert got.cycles == 4
    np.testing.assert_allclose(got.rp, expected.rp, atol=TOL)


def test_rejects_non_matrix_input():
    with pytest.raises(ValueError):
        point_statistics([1.0, 2.0])
    with pytest.raises(ValueError):
        point_statistics(np.zeros((0, 3)))


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 5), st.integers(2, 8)),
              elements=st.floats(0.2e-3, 2.2e-3)),
       st.data())
def test_running_statistics_equal_first_k_columns(d, data):
    m, n = d.shape
    k = data.draw(st.integers(1, n - 1))
    partial = np.full_like(d, math.nan)
    partial[:, :k] = d[:, :k]
    partial[:data.draw(st.integers(0, m - 1)), k] = d[0, k]  # cycle k under way
    running, first_k = point_statistics(partial), point_statistics(d[:, :k])
    assert running.cycles == first_k.cycles == k
    for field in ('mean_distance', 'mean_deviation', 'sigma', 'rp'):
        np.testing.assert_array_equal(getattr(running, field), getattr(first_k, field))
    np.testing.assert_equal(running.rp_all, first_k.rp_all)


# eq (14) on the published tables (mm). Each RP_i is rounded to 0.01, so the mean of the
# rounded RP_i and the rounded RP_all may differ by up to 0.005 + 0.005. Only the rows that
# satisfy this are listed: Table 1 RPS (mean 0.665 vs 0.70), Table 3 RPS (1.24 vs 1.42),
# Table 4 three-points (0.296 vs 0.33), Table 5 five-points (0.342 vs 0.36) and reference
# (0.21 vs 0.24) do not, so the paper's RP_all there is not the plain mean of its RP_i.
@pytest.mark.parametrize('rp_i, rp_all', [
    ([0.10, 0.05, 0.07, 0.09], 0.08),        # Table 1, reference
    ([0.36, 0.52, 0.30, 0.35], 0.39),        # Table 2, RPS
    ([0.08, 0.15, 0.20, 0.19], 0.16),        # Table 2, reference
    ([0.04, 0.14, 0.06, 0.04], 0.08),        # Table 3, reference (0.07, at the limit)
    ([0.08, 0.13, 0.19, 0.10, 0.08], 0.12),  # Table 4, five-points
    ([0.04, 0.07, 0.12, 0.11, 0.05], 0.08),  # Table 4, reference
    ([0.52, 0.38, 0.49, 0.69, 0.54], 0.53),  # Table 5, three-points
])
def test_overall_rp_matches_paper_tables(rp_i, rp_all):
    assert overall_rp(np.array(rp_i) * MM) == pytest.approx(rp_all * MM, abs=0.0101 * MM)


# eq (15), probe range of the paper (0.2-2.2 mm), safe margin 0.1 mm -> band 0.3-2.1 mm,
# default target the middle of the range, 1.2 mm.
G_MIN, G_MAX, MARGIN = 0.2 * MM, 2.2 * MM, 0.1 * MM


def test_out_of_range_point_is_moved_closer_and_reading_corrected_up():
    # Predicted gap 2.5 mm > 2.1: FF = 2.5 - 1.2 = 1.3 mm, commanded F - FF ('closer').
    ff, direction = range_correction(2.5 * MM, G_MIN, G_MAX, MARGIN)
    assert direction == 'closer'
    assert ff == pytest.approx(1.3 * MM, abs=TOL)
    # The robot lands 0.05 mm off: true gap at F would be 2.55 mm, the probe reads
    # 2.55 - 1.3 = 1.25 mm; eq (15) first line: d := d + FF = 1.25 + 1.3 = 2.55 mm.
    assert correct_distance(1.25 * MM, ff, direction) == pytest.approx(2.55 * MM, abs=TOL)


def test_too_close_point_is_moved_away_and_reading_corrected_down():
    # Predicted gap 0.1 mm < 0.3: FF = 1.2 - 0.1 = 1.1 mm, commanded F + FF ('away').
    ff, direction = range_correction(0.1 * MM, G_MIN, G_MAX, MARGIN)
    assert direction == 'away'
    assert ff == pytest.approx(1.1 * MM, abs=TOL)
    # True gap at F 0.12 mm, the probe reads 0.12 + 1.1 = 1.22 mm;
    # eq (15) second line: d := d - FF = 1.22 - 1.1 = 0.12 mm.
    assert correct_distance(1.22 * MM, ff, direction) == pytest.approx(0.12 * MM, abs=TOL)


def test_point_inside_the_band_is_not_corrected():
    assert range_correction(0.31 * MM, G_MIN, G_MAX, MARGIN) == (0.0, None)
    assert range_correction(2.09 * MM, G_MIN, G_MAX, MARGIN) == (0.0, None)
    assert correct_distance(1.0 * MM, 0.0, None) == 1.0 * MM


def test_range_correction_to_a_custom_target():
    ff, direction = range_correction(0.1 * MM, G_MIN, G_MAX, MARGIN, g_target=0.5 * MM)
    assert (ff, direction) == (pytest.approx(0.4 * MM, abs=TOL), 'away')


@pytest.mark.parametrize('args', [
    (1.0 * MM, G_MIN, G_MAX, -0.1 * MM),            # negative margin
    (1.0 * MM, G_MIN, G_MAX, 1.0 * MM),             # margin leaves no band
    (1.0 * MM, G_MAX, G_MIN, 0.0),                  # range upside down
    (math.nan, G_MIN, G_MAX, MARGIN),               # no prediction
    (1.0 * MM, G_MIN, G_MAX, MARGIN, 0.25 * MM),    # target outside the band
])
def test_range_correction_rejects_bad_arguments(args):
    with pytest.raises(ValueError):
        range_correction(*args)


@pytest.mark.parametrize('ff, direction', [(-0.1 * MM, 'away'), (0.1 * MM, 'up'),
                                           (0.1 * MM, None)])
def test_correct_distance_rejects_bad_arguments(ff, direction):
    with pytest.raises(ValueError):
        correct_distance(1.0 * MM, ff, direction)


@given(st.floats(-5.0e-3, 8.0e-3), st.floats(-0.5e-3, 0.5e-3))
def test_corrected_reading_refers_to_the_uncorrected_commanded_point(predicted, error):
    ff, direction = range_correction(predicted, G_MIN, G_MAX, MARGIN)
    true_gap = predicted + error  # gap the probe would read at the uncorrected point [m]
    moved = {'away': ff, 'closer': -ff, None: 0.0}[direction]
    reading = true_gap + moved
    assert correct_distance(reading, ff, direction) == pytest.approx(true_gap, abs=TOL)
    assert G_MIN + MARGIN - TOL <= predicted + moved <= G_MAX - MARGIN + TOL


def test_probe_offset_moves_the_gap_to_the_middle_of_the_range():
    # Middle of 0.2-2.2 mm is 1.2 mm: a 2.0 mm gap needs -0.8 mm (closer),
    # a 0.3 mm gap +0.9 mm (away); F_i = z_R + offset in the paper's z set-up.
    assert probe_offset(2.0 * MM, G_MIN, G_MAX) == pytest.approx(-0.8 * MM, abs=TOL)
    assert probe_offset(0.3 * MM, G_MIN, G_MAX) == pytest.approx(0.9 * MM, abs=TOL)
    assert probe_offset(0.3 * MM, G_MIN, G_MAX, 1.0 * MM) == pytest.approx(0.7 * MM, abs=TOL)
    assert math.isnan(probe_offset(math.nan, G_MIN, G_MAX))
    with pytest.raises(ValueError):
        probe_offset(1.0 * MM, G_MIN, G_MAX, 3.0 * MM)


# ISO 9283 RP_l. Positions c + (1, 2, 2), c - (1, 2, 2), c + (0, 0, 1), c - (0, 0, 1) mm:
# mean c; l = 3, 3, 1, 1 (|(1, 2, 2)| = sqrt(1 + 4 + 4) = 3); l-bar = 8 / 4 = 2;
# l - l-bar = 1 1 -1 -1, S_l = sqrt(4 / 3) = 2 / sqrt(3); RP_l = 2 + 3 * 2 / sqrt(3)
# = 2 + 2 sqrt(3) = 5.4641016151 mm.
RP_L_MM = 5.4641016151
CENTRE_MM = np.array([400.0, -150.0, 30.0])
OFFSETS_MM = np.array([[1.0, 2.0, 2.0], [-1.0, -2.0, -2.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])


def test_iso_rp_3d_hand_computed():
    positions = (CENTRE_MM + OFFSETS_MM) * MM
    assert iso9283_rp_3d(positions) == pytest.approx(RP_L_MM * MM, abs=1e-9 * MM)


def test_iso_rp_3d_regular_tetrahedron_has_zero_spread():
    # Every vertex of (1,1,1) (1,-1,-1) (-1,1,-1) (-1,-1,1) is sqrt(3) from the mean:
    # S_l = 0 and RP_l = sqrt(3) = 1.7320508076 mm.
    tetra = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0],
                      [-1.0, -1.0, 1.0]]) * MM
    assert iso9283_rp_3d(tetra) == pytest.approx(1.7320508076 * MM, abs=1e-9 * MM)


def test_iso_rp_3d_drops_incomplete_rows_and_needs_two():
    positions = np.vstack([(CENTRE_MM + OFFSETS_MM) * MM, [[math.nan, 0.0, 0.0]]])
    assert iso9283_rp_3d(positions) == pytest.approx(RP_L_MM * MM, abs=1e-9 * MM)
    assert math.isnan(iso9283_rp_3d([[0.0, 0.0, 0.0]]))
    with pytest.raises(ValueError):
        iso9283_rp_3d(np.zeros((4, 2)))


def test_iso_rp_from_axes_combines_runs_cycle_by_cycle():
    # The same set as above, one axis per run; each run has its own marker offset [mm].
    dx = np.array([1.0, -1.0, 0.0, 0.0]) + 1.1
    dy = np.array([2.0, -2.0, 0.0, 0.0]) + 0.7
    dz = np.array([2.0, -2.0, 1.0, -1.0]) + 1.5
    rp = iso9283_rp_from_axes(dx * MM, dy * MM, dz * MM)
    assert rp == pytest.approx(RP_L_MM * MM, abs=1e-9 * MM)
    with pytest.raises(ValueError):
        iso9283_rp_from_axes(dx, dy, dz[:3])


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.integers(2, 30), elements=st.floats(0.2e-3, 2.2e-3)))
def test_paper_rp_is_iso_rp_along_one_axis(d):
    zeros = np.zeros_like(d)
    expected = point_statistics(d[np.newaxis, :]).rp[0]
    assert iso9283_rp_from_axes(zeros, zeros, d) == pytest.approx(expected, abs=TOL)
