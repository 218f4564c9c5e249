"""Repeatability report: hand-computed table numbers in mm, a readable PNG, clear errors."""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cobot_calib_ros.api import report
from cobot_calib_ros.store.trials import TrialStore

MM = 1e-3  # [m]
NAN = math.nan
PNG_MAGIC = b'\x89PNG\r\n\x1a\n'

# Three cycles; signed deviations +h, +2h, -3h from the mean, so by hand:
#   eq (9)  d-bar_i = the centre value
#   eq (10) D_i,n = h, 2h, 3h
#   eq (11) D-bar_i = 6h / 3 = 2h
#   eq (12) D - D-bar = -h, 0, +h -> squares sum 2h^2, / (n - 1 = 2) = h^2 -> sigma_i = h
#   eq (13) RP_i = 2h + 3h = 5h
# P1: centre 1.20 mm, h = 0.01 mm -> D-bar 0.020, sigma 0.010, RP 0.050 mm
# P2: centre 0.80 mm, h = 0.02 mm -> D-bar 0.040, sigma 0.020, RP 0.100 mm
# eq (14) RP_all = (0.050 + 0.100) / 2 = 0.075 mm
DISTANCES_MM = [[1.21, 1.22, 1.17],
                [0.82, 0.84, 0.74]]
EXPECTED_ROWS = {'P1': ['1.200', '0.020', '0.010', '0.050'],
                 'P2': ['0.800', '0.040', '0.020', '0.100']}


def _make_trial(store: TrialStore, trial_id: str, distances_mm, method: str = 'reference',
                cycles_total: int | None = None, axis: str = 'z') -> None:
    """A trial whose readings are ``distances_mm`` (points x cycles [mm], NaN: not measured)."""
    d = np.asarray(distances_mm, dtype=float)
    store.create(trial_id, method=method, axis=axis, layout='close',
                 point_names=[f'P{i + 1}' for i in range(d.shape[0])],
                 cycles_total=cycles_total or d.shape[1], stamp_ns=1)
    for cycle in range(d.shape[1]):
        for point in range(d.shape[0]):
            if math.isfinite(d[point, cycle]):
                store.append(trial_id, cycle, point, d[point, cycle] * MM, stamp_ns=2)


def _row(table: str, first_cell: str) -> list[str]:
    """The whitespace-split cells of the (first) table line starting with ``first_cell``."""
    for line in table.splitlines():
        cells = line.split()
        if cells and cells[0] == first_cell:
            return cells
    raise AssertionError(f'no row {first_cell!r} in\n{table}')


@pytest.fixture
def store(tmp_path):
    return TrialStore(tmp_path / 'data')


def test_summary_holds_hand_computed_numbers_in_mm(store):
    _make_trial(store, 'ref', DISTANCES_MM)
    summary = report.trial_summary(store.load('ref'))
    assert {k: summary[k] for k in ('id', 'method', 'axis', 'layout', 'cycles')} == {
        'id': 'ref', 'method': 'reference', 'axis': 'z', 'layout': 'close', 'cycles': 3}
    p1, p2 = summary['points']
    assert p1['name'] == 'P1' and p2['name'] == 'P2'
    assert p1['mean_d_mm'] == pytest.approx(1.20, abs=1e-9)
    assert p1['mean_D_mm'] == pytest.approx(0.02, abs=1e-9)
    assert p1['sigma_mm'] == pytest.approx(0.01, abs=1e-9)
    assert p1['rp_mm'] == pytest.approx(0.05, abs=1e-9)
    assert p2['rp_mm'] == pytest.approx(0.10, abs=1e-9)
    assert summary['rp_all_mm'] == pytest.approx(0.075, abs=1e-9)
    assert summary['note'] is None


def test_table_has_paper_rp_row_and_per_point_details_with_units(store):
    _make_trial(store, 'ref', DISTANCES_MM)
    _make_trial(store, 'rig', np.array(DISTANCES_MM) * 2, method='rigid')  # everything x2
    table = report.format_table([report.trial_summary(store.load(i)) for i in ('ref', 'rig')])
    assert _row(table, 'Experiment') == ['Experiment', 'RP_P1', '[mm]', 'RP_P2', '[mm]',
                                         'RP_all', '[mm]', 'paper', 'RP_all', '[mm]',
                                         'calibration', '[s]']
    # the paper's Table 4 beside the reference (close, z); no paper value and no calibration
    # pass time for rigid (these hand-made trials store none)
    assert _row(table, 'reference') == ['reference', '(ref)', '0.050', '0.100', '0.075',
                                        '0.08', '(Table', '4)', 'n/a']
    assert _row(table, 'rigid') == ['rigid', '(rig)', '0.100', '0.200', '0.150', 'n/a', 'n/a']
    assert _row(table, 'Point') == ['Point', 'mean', 'd_i', '[mm]', 'mean', 'D_i', '[mm]',
                                    'sigma_i', '[mm]', 'RP_i', '[mm]']
    assert _row(table, 'P1')[1:] == EXPECTED_ROWS['P1']  # first block: the reference
    assert _row(table, 'P2')[1:] == EXPECTED_ROWS['P2']
    assert 'RP_all = 0.075 mm' in table and 'RP_all = 0.150 mm' in table
    assert 'Trial ref: method reference, z-axis, layout close, 3 of 3 cycles' in table
    assert 'nan' not in table.lower()


def test_partially_measured_trial_uses_complete_cycles_only(store):
    partial = np.column_stack([DISTANCES_MM, [1.50, NAN], [NAN, NAN]])  # cycle 3 half done
    _make_trial(store, 'part', partial)
    summary = report.trial_summary(store.load('part'))
    assert summary['cycles'] == 3 and summary['cycles_total'] == 5
    assert summary['rp_all_mm'] == pytest.approx(0.075, abs=1e-9)
    table = report.format_table([summary])
    assert _row(table, 'P1')[1:] == EXPECTED_ROWS['P1']
    assert '3 of 5 cycles complete (status running)' in table


def test_trial_with_fewer_than_two_cycles_reports_none_and_a_note(store):
    _make_trial(store, 'one', [[1.2], [0.8]], cycles_total=30)
    summary = report.trial_summary(store.load('one'))
    assert summary['cycles'] == 1 and summary['rp_all_mm'] is None
    assert all(v is None for p in summary['points']
               for k, v in p.items() if k != 'name')
    assert '2 are needed' in summary['note']
    table = report.format_table([summary])
    assert _row(table, 'P1')[1:] == ['n/a'] * 4
    assert 'RP_all = n/a mm' in table and 'note:' in table and 'nan' not in table.lower()


def test_rp_all_skips_points_without_rp_and_says_so():
    points = [{'name': 'P1', 'rp_mm': 0.05}, {'name': 'P2', 'rp_mm': None},
              {'name': 'P3', 'rp_mm': 0.10}]
    rp_all, note = report._rp_all_mm(points, cycles=30)
    assert rp_all == pytest.approx(0.075)
    assert note == 'RP_all over 2 of 3 points; no RP_i for P2'


def test_box_plot_writes_a_readable_png(store, tmp_path):
    import matplotlib.image

    _make_trial(store, 'ref', DISTANCES_MM)
    _make_trial(store, 'rig', np.column_stack([DISTANCES_MM, [1.5, NAN]]), method='rigid')
    out = tmp_path / 'out'
    out.mkdir()
    path = report.box_plot([store.load('ref'), store.load('rig')], out / 'plot.png', 'Test')
    assert path == out / 'plot.png'
    assert path.read_bytes()[:8] == PNG_MAGIC
    height, width, _ = matplotlib.image.imread(path).shape
    assert width >= 800 and height >= 400
    assert os.listdir(out) == ['plot.png']  # no temporary file left behind


def test_box_plot_groups_one_box_per_point_and_trial(store):
    _make_trial(store, 'ref', DISTANCES_MM)
    _make_trial(store, 'rig', DISTANCES_MM, method='rigid')
    figure = report._box_figure([store.load('ref'), store.load('rig')], None)
    [ax] = figure.axes
    assert [t.get_text() for t in ax.get_xticklabels()] == ['P1', 'P2']
    assert '[mm]' in ax.get_ylabel()
    [legend] = figure.legends
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels[:4] == ['z: reference (ref, n = 3 cycles, RP_all 0.075 mm)',
                          'z: rigid (rig, n = 3 cycles, RP_all 0.075 mm)', 'median', 'mean']
    assert len(ax.patches) == 4  # 2 points x 2 trials (box patches)
    top = max(max(line.get_ydata(), default=-1.0) for line in ax.lines)
    assert top == pytest.approx(1.25)  # mm, not metres: P1's band 1.200 + RP 0.050


def test_box_plot_one_panel_per_axis_rp_written_mid_range_marked_legend_apart(store):
    """As ISO 9283 reports: each probed axis in its own panel, RP_i written at each box (the
    hand-computed 0.050 / 0.100 mm), the band mean d_i +- RP_i drawn, the probe's mid-range
    (stored with the trial) across every panel, and a legend that covers no panel."""
    probe = {'probe_range_m': [0.4e-3, 2.0e-3]}            # mid-range 1.2 mm
    for trial_id, axis in (('rx', 'x'), ('rz', 'z')):
        d = np.asarray(DISTANCES_MM) * MM
        store.create(trial_id, method='reference', axis=axis, layout='close',
                     point_names=['P1', 'P2'], cycles_total=3, stamp_ns=1, extra=probe)
        for cycle in range(3):
            for point in range(2):
                store.append(trial_id, cycle, point, d[point, cycle], stamp_ns=2)
    _make_trial(store, 'tz', [[1.2, 1.3, 1.1], [0.8, 0.8, 0.8]], method='three_point')
    trials = [store.load(i) for i in ('rz', 'rx', 'tz')]
    assert report.probe_mid_range_mm(trials) == pytest.approx(1.2)
    figure = report._box_figure(trials, None)
    figure.canvas.draw()
    x_panel, z_panel = figure.axes
    assert (x_panel.get_title(), z_panel.get_title()) == ('x-axis', 'z-axis')
    assert len(x_panel.patches) == 2 and len(z_panel.patches) == 4   # boxes: points x trials
    texts = {ax.get_title(): [t.get_text() for t in ax.texts] for ax in figure.axes}
    # tz: P1 deviations 0, 0.1, 0.1 -> D-bar 0.0667, sigma 0.0577, RP 0.240; P2 all equal
    assert texts == {'x-axis': ['0.050', '0.100'],
                     'z-axis': ['0.050', '0.100', '0.240', '0.000']}
    for ax in figure.axes:
        mid = [line for line in ax.lines if line.get_linestyle() == ':']
        assert [tuple(line.get_ydata()) for line in mid] == [(1.2, 1.2)]
    # the bands: reference P1 1.200 +- 0.050, three_point P2 0.800 +- 0
    errorbars = [c for c in z_panel.containers if type(c).__name__ == 'ErrorbarContainer']
    low_high = sorted(tuple(np.round(seg[:, 1], 6)) for c in errorbars
                      for seg in c.lines[2][0].get_segments())
    assert (1.15, 1.25) in low_high and (0.8, 0.8) in low_high
    [legend] = figure.legends
    box = legend.get_window_extent()
    assert not any(box.overlaps(ax.get_window_extent()) for ax in figure.axes)
    labels = [t.get_text() for t in legend.get_texts()]
    assert 'probe mid-range 1.200 mm' in labels


def test_write_report_writes_png_and_markdown_table(store, tmp_path):
    _make_trial(store, 'ref', DISTANCES_MM)
    _make_trial(store, 'rig', DISTANCES_MM, method='rigid')
    png, table_path, table = report.write_report(store, ['ref', 'rig'], tmp_path / 'reports')
    assert png.name == 'repeatability_ref+rig.png' and png.read_bytes()[:8] == PNG_MAGIC
    markdown = table_path.read_text()
    assert table_path.suffix == '.md' and table.rstrip() in markdown
    assert f'![probe distances]({png.name})' in markdown


def test_write_report_lists_ignored_measurement_lines(store, tmp_path):
    _make_trial(store, 'ref', DISTANCES_MM)
    with open(store.directory / 'ref' / 'distances.csv', 'a') as f:
        f.write('garbage,line\n')
    _, table_path, _ = report.write_report(store, ['ref'], tmp_path)
    assert 'ignored line' in table_path.read_text()


def test_unknown_and_malformed_trial_ids_are_named_with_the_known_ones(store, tmp_path):
    _make_trial(store, 'ref', DISTANCES_MM)
    with pytest.raises(ValueError) as excinfo:
        report.write_report(store, ['ref', 'nope', '../etc'], tmp_path)
    message = str(excinfo.value)
    assert "'nope': unknown trial" in message
    assert "'../etc': not a valid trial id" in message
    assert 'ref' in message and 'Pick existing trial ids' in message
    assert not list(tmp_path.glob('*.png'))


def test_unreadable_trial_is_named_with_the_reason(store, tmp_path):
    _make_trial(store, 'ref', DISTANCES_MM)
    (store.directory / 'ref' / 'trial.yaml').write_text('- not a mapping\n')
    with pytest.raises(ValueError, match=r"'ref': unreadable \(.*not a mapping"):
        report.write_report(store, ['ref'], tmp_path)


def test_no_trial_ids_is_an_error(store, tmp_path):
    with pytest.raises(ValueError, match='no trial ids'):
        report.write_report(store, [], tmp_path)


def test_importing_the_module_does_not_load_matplotlib_or_rclpy():
    code = ('import sys, cobot_calib_ros.api.report; '
            'print(sorted(m for m in ("matplotlib", "rclpy") if m in sys.modules))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == '[]'


def test_three_axis_trials_give_the_iso_3d_repeatability(store, tmp_path):
    """x deviations +-0.03, y +-0.04, z none: every attained position is 0.05 mm from the
    mean (3-4-5), so l-bar = 0.050 mm, S_l = 0 and RP_l = 0.050 mm (ISO 9283 7.2.2)."""
    _make_trial(store, 'x', [[1.23, 1.17, 1.23, 1.17]], 'rigid', axis='x')
    _make_trial(store, 'y', [[0.94, 0.86, 0.94, 0.86]], 'rigid', axis='y')
    _make_trial(store, 'z', [[1.10, 1.10, 1.10, 1.10]], 'rigid', axis='z')
    _make_trial(store, 'ref', [[1.2, 1.2, 1.2, 1.2]], 'reference')   # z only: no 3D row
    _, _, table = report.write_report(store, ['x', 'y', 'z', 'ref'], tmp_path / 'out')
    three_d = table.split('three-dimensional')[1]
    assert _row(three_d, 'rigid')[1:] == ['0.050', '4']
    with pytest.raises(AssertionError):
        _row(three_d, 'reference')


def test_the_table_shows_the_mean_calibration_time_and_the_papers_rps_figure(store):
    _make_trial(store, 'rps', DISTANCES_MM, method='landmark_single')
    for cycle, seconds in enumerate((1.5, 2.5, None)):     # the third cycle stored no time
        if seconds is not None:
            store.record_calibration_time('rps', cycle, seconds)
    summary = report.trial_summary(store.load('rps'))
    assert summary['calibration_s'] == pytest.approx(2.0)
    table = report.format_table([summary])
    assert _row(table, 'landmark_single')[-4:] == ['1.42', '(Table', '3)', '2.0']
