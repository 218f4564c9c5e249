"""`cobot-calib history` on a database the simulated cell filled (no ROS): the change of each
calibration with its standard error, the drift verdicts, the trend PNG, --since and --cell."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import calibrate_user_frame, moved_table
from cobot_calib_ros.store.records import UserFrameRecord

SIM = load_simulation(cell_file('sawyer_close'))
DAY_NS = 86_400 * 10 ** 9
NOV_1 = 1_793_491_200 * 10 ** 9       # 2026-11-01T00:00:00Z


@pytest.fixture
def filled(tmp_path):
    url = f'sqlite:///{tmp_path / "plant.sqlite"}'
    sims = {'cell_07': [SIM, SIM, moved_table(SIM, [0, 3e-4, 0]), moved_table(SIM, [0, 3e-4, 0])],
            'cell_08': [SIM, SIM]}
    for cell, runs in sims.items():
        repo = store.open(tmp_path / cell, url, cell)
        for day, sim in enumerate(runs):
            run = calibrate_user_frame(sim, 10 + day)
            record = UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                              ('base', 'user'), NOV_1 + day * DAY_NS)
            record.id = f'{cell}-day{day}'
            repo.user_frames.save_and_activate(record)
    return tmp_path, url


def test_history_json_gives_each_change_with_its_uncertainty_and_verdict(filled, capsys):
    root, url = filled
    code = main(['history', '--json', '--db', url, '--data-dir', str(root),
                 '--plots', str(root / 'png')])
    out = capsys.readouterr().out.splitlines()
    reports = {r['cell']: r for r in map(json.loads, out[:2])}
    assert code == 0 and set(reports) == {'cell_07', 'cell_08'}
    steps = reports['cell_07']['user_frames']
    assert [s['verdict'] for s in steps] == ['first', 'OK', 'WARN', 'OK']
    moved = steps[2]
    assert 0.2 < moved['moved_mm'] < 0.4 and 0 < moved['sigma_mm'] < 0.1
    assert moved['previous'] == 'cell_07-day1' and 'recalibrate' in moved['message']
    assert [s['verdict'] for s in reports['cell_08']['user_frames']] == ['first', 'OK']
    assert out[2:] == [f'trend plot: {root / "png" / f"history-{c}.png"}'
                       for c in ('cell_07', 'cell_08')]
    assert (root / 'png' / 'history-cell_07.png').read_bytes()[:4] == b'\x89PNG'


def test_history_since_and_cell_select(filled, capsys):
    root, url = filled
    assert main(['history', '--json', '--no-plots', '--db', url, '--data-dir', str(root),
                 '--cell', 'cell_07', '--since', '2026-11-03']) == 0
    report, = map(json.loads, capsys.readouterr().out.splitlines())
    assert [s['id'] for s in report['user_frames']] == ['cell_07-day2', 'cell_07-day3']
    assert main(['history', '--since', 'last tuesday', '--data-dir', str(root)]) == 2
    assert 'not an ISO 8601 time' in capsys.readouterr().err


def test_history_table_names_the_warning(filled, capsys):
    root, url = filled
    assert main(['history', '--no-plots', '--db', url, '--data-dir', str(root),
                 '--cell', 'cell_07']) == 0
    out = capsys.readouterr().out
    assert 'cell cell_07: 4 user frame(s)' in out
    assert 'WARN: user frame moved 0.' in out and 'since cell_07-day1' in out


def test_history_of_an_unknown_cell_names_the_known_ones(filled, capsys):
    """Issue 31 item 9: it answered 'cell typo: 0 user frame(s)'."""
    root, url = filled
    assert main(['history', '--no-plots', '--db', url, '--data-dir', str(root),
                 '--cell', 'typo']) == 2
    captured = capsys.readouterr()
    assert '0 user frame(s)' not in captured.out
    assert (f"history: no results of cell 'typo' in {root}; the cells with results: "
            'cell_07, cell_08') in captured.err


def test_history_keeps_results_from_before_the_keying_apart(tmp_path, capsys):
    """Cell 'default' (stored before results were keyed by cell) shows those alone; the cell
    of their robot shows them with its own; another robot's cell none of them."""
    from cobot_calib_ros.store.cells import ResultsCell
    url = f'sqlite:///{tmp_path / "plant.sqlite"}'
    legacy = _frame_record(SIM, 0, 'before-keying')
    legacy_dict = {**legacy.to_dict(), 'robot': 'sawyer'}
    store.open(tmp_path, url).user_frames.save_and_activate(legacy_dict)   # as 85479bc did
    store.open(tmp_path, url, ResultsCell('sawyer_close', 'sawyer')).user_frames \
        .save_and_activate(_frame_record(SIM, 1, 'sawyer-own'))
    store.open(tmp_path, url, ResultsCell('iiwa7_close', 'iiwa7')).user_frames \
        .save_and_activate(_frame_record(SIM, 2, 'iiwa-own'))
    assert main(['history', '--json', '--no-plots', '--db', url, '--data-dir',
                 str(tmp_path)]) == 0
    reports = {r['cell']: [s['id'] for s in r['user_frames']]
               for r in map(json.loads, capsys.readouterr().out.splitlines())}
    assert reports == {'default': ['before-keying'], 'iiwa7_close': ['iiwa-own'],
                       'sawyer_close': ['before-keying', 'sawyer-own']}


def _frame_record(sim, day: int, record_id: str) -> UserFrameRecord:
    run = calibrate_user_frame(sim, 10 + day)
    record = UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                      ('base', 'user'), NOV_1 + day * DAY_NS)
    record.id = record_id
    return record


def test_history_help_says_one_json_line_per_cell(capsys):
    """Issue 31.9: the help said one JSON line per result; it prints one per cell (README)."""
    with pytest.raises(SystemExit):
        main(['history', '--help'])
    help_text = ' '.join(capsys.readouterr().out.split())
    assert 'one JSON line per cell' in help_text and 'per result' not in help_text


def test_the_trend_plot_labels_each_calibration_and_draws_both_tolerances(filled, capsys):
    """Issue 31.9: the PNG had ticks at 1.5, 2.5 ..., no ERROR line, no dates or ids."""
    from cobot_calib_ros.cli.history import trend_figure
    root, url = filled
    assert main(['history', '--json', '--no-plots', '--db', url, '--data-dir', str(root),
                 '--cell', 'cell_07']) == 0
    report = json.loads(capsys.readouterr().out)
    fig = trend_figure(report)
    moved, turned = fig.axes
    assert list(turned.get_xticks()) == [1, 2, 3]
    assert [t.get_text() for t in turned.get_xticklabels()] == [
        f'2026-11-0{day + 1} 00:00\ncell_07-day{day}' for day in (1, 2, 3)]
    for ax, warn, error in ((moved, 0.2, 1.0), (turned, 1.0, 5.0)):
        lines = {line.get_label(): line.get_ydata()[0] for line in ax.get_lines()}
        assert lines['WARN tolerance'] == pytest.approx(warn)
        assert lines['ERROR tolerance'] == pytest.approx(error)


def test_a_failing_history_keeps_its_exit_code_when_its_reader_leaves(tmp_path):
    """Issue 31.9: `history | head -1` at ERROR exited 0: the print into the closed pipe
    raised BrokenPipeError, which main turned into success."""
    import os
    import subprocess
    import sys
    url = f'sqlite:///{tmp_path / "plant.sqlite"}'
    repo = store.open(tmp_path, url, 'cell_09')
    for day, sim in enumerate([SIM, moved_table(SIM, [0, 2e-3, 0])]):
        run = calibrate_user_frame(sim, 10 + day)
        record = UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                          ('base', 'user'), NOV_1 + day * DAY_NS)
        record.id = f'cell_09-day{day}'
        repo.user_frames.save_and_activate(record)
    command = [sys.executable, '-m', 'cobot_calib_ros.cli.main', 'history', '--no-plots',
               '--db', url, '--data-dir', str(tmp_path), '--cell', 'cell_09']
    whole = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert whole.returncode == 1 and 'ERROR: user frame moved ' in whole.stdout
    cut = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           env=dict(os.environ))
    cut.stdout.close()                         # the reader has gone before the first line
    _, err = cut.communicate(timeout=60)
    assert cut.returncode == 1, err.decode()
    assert b'Traceback' not in err and b'BrokenPipe' not in err


def test_history_lists_every_kind_and_says_which_active_result_is_stale(tmp_path, capsys):
    """Issue 36.2: a user frame touched with TCP t1 is stale once t2 is active (one line with
    both ids and the TCPs' distance at the tool); every kind is listed, the active ones
    marked (on 12237a8 `--json` had "kinematics": [] with one active)."""
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.store.cells import ResultsCell
    cell = SIM.cell
    model = model_for(cell)
    repo = store.open(tmp_path, cell=ResultsCell.of(cell))
    repo.kinematics.save_and_activate({
        'id': 'k1', 'stamp_ns': NOV_1, 'method': 'test', 'robot': model.name, 'inputs': {},
        'measured_through': {}, 'result': {'parameter_names': list(model.parameter_names),
                                           'params': list(model.nominal), 'rms_m': 1e-5}})
    for day, (tcp_id, dz) in enumerate((('t1', 0.0), ('t2', 1e-4))):
        T = np.array(cell.T_flange_tool)
        T[2, 3] += dz
        repo.tcp.save_and_activate({
            'id': tcp_id, 'stamp_ns': NOV_1 + (2 * day + 1) * DAY_NS, 'method': 'tcp-4-point',
            'tool': cell.tool_frame, 'inputs': {}, 'measured_through': {'kinematics': 'k1'},
            'result': {'T_flange_tool': T.tolist(), 'orientation_method': 'none',
                       'mean_residual_mm': 0.02, 'max_residual_mm': 0.03}})
        if tcp_id == 't1':
            run = calibrate_user_frame(SIM, 10)
            record = UserFrameRecord.from_fit(
                run.fit, None, run.names, run.p_user, run.p_base, ('base', 'user'),
                NOV_1 + 2 * DAY_NS, 'k1', tcp='t1',
                measured_through={'kinematics': 'k1', 'tcp': 't1'})
            record.id = 'F'
            repo.user_frames.save_and_activate(record)
    assert main(['history', '--json', '--no-plots', '--data-dir', str(tmp_path)]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [(k['id'], k['active'], k['previous']) for k in report['kinematics']] == [
        ('k1', True, '')]
    assert [(t['id'], t['active']) for t in report['tcp']] == [('t1', False), ('t2', True)]
    assert report['user_frames'][0]['measured_through'] == {'kinematics': 'k1', 'tcp': 't1'}
    assert report['hand_eye'] == [] and report['intrinsics'] == []
    (stale,) = report['stale']
    assert (stale['kind'], stale['id'], stale['was'], stale['now']) == ('user_frame', 'F',
                                                                         't1', 't2')
    assert stale['change_mm'] == pytest.approx(0.1, abs=1e-9)
    assert stale['message'] == ('user frame F was touched with TCP t1; the active TCP t2 is '
                                '0.100 mm away at the tool: touch the frame again, or keep it')
    assert main(['history', '--no-plots', '--data-dir', str(tmp_path)]) == 0
    assert f'  stale: {stale["message"]}' in capsys.readouterr().out.splitlines()
