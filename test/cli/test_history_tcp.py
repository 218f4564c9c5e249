"""`cobot-calib history` lists each tool's TCPs with their drift (store.history.tcp_steps), from
TCP calibrations of the simulated cell (no ROS)."""
from __future__ import annotations

import json

from cobot_calib_ros import store
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.tcp_run import calibrate_tcp, moved_tool
from cobot_calib_ros.store.records import TcpRecord

SIM = load_simulation(cell_file('sawyer_close'))
DAY_NS = 86_400 * 10 ** 9


def test_history_gives_each_tcp_change_with_its_uncertainty_and_verdict(tmp_path, capsys):
    url = f'sqlite:///{tmp_path / "plant.sqlite"}'
    repo = store.open(tmp_path, url, 'cell_tcp')
    for day, sim in enumerate([SIM, SIM, moved_tool(SIM, [0.0, 4e-4, 0.0])]):
        run = calibrate_tcp(sim, 20 + day, count=8, exact_kinematics=True)
        record = TcpRecord.from_solution(run.solution, 'tool0', 'P1', run.touches.labels,
                                         run.touches.joints, run.touches.flange,
                                         (day + 1) * DAY_NS)
        record.id = f'tcp-day{day}'
        assert repo.tcp.save_and_activate(record)
    assert main(['history', '--json', '--no-plots', '--db', url, '--data-dir',
                 str(tmp_path)]) == 0
    report = json.loads(capsys.readouterr().out)
    steps = report['tcp']
    assert [(s['tool'], s['verdict']) for s in steps] == [
        ('tool0', 'first'), ('tool0', 'OK'), ('tool0', 'WARN')]
    assert 0.3 < steps[2]['moved_mm'] < 0.5 and 0 < steps[2]['sigma_mm'] < 0.05
    assert steps[2]['previous'] == 'tcp-day1' and 'TCP of tool0 moved' in steps[2]['message']
    assert abs(steps[0]['xyz_mm'][2] - 100.24) < 0.05
    assert main(['history', '--no-plots', '--db', url, '--data-dir', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'tcp tool0 tcp-day2 (tcp-8-point): ' in out and 'WARN: TCP of tool0 moved 0.' in out
