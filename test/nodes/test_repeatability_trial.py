"""run_trial and the live repeatability topic, across processes, through the CLI users type."""
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from action_msgs.srv import CancelGoal
from cobot_calib_msgs.action import RunTrial
from cobot_calib_msgs.msg import Repeatability
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest

from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import CallError, run_action, spin_until
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.core.repeatability import point_statistics
from cobot_calib_ros.ros import qos
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.trials import TrialStore
from proc_lines import Lines
from rosutil import (
    call, cli, cli_command, STARTUP_TIMEOUT, STOP_TIMEOUT, wait_goals_ended, wait_subscribed)

CYCLES = 4
HEALTH = 'repeatability_trial: health'


def trial_command(ros_args=(), **args) -> list[str]:
    """`cobot-calib trial` as run_trial runs it with these parsed options; an option left out
    is None, as argparse gives it when it has no default."""
    code = ('import argparse, json, sys; from cobot_calib_ros.cli import experiment; '
            'sys.exit(experiment.run_trial(argparse.Namespace(**json.loads(sys.argv[1]))))')
    options = {'method': None, 'axis': None, 'cycles': None, 'trial_id': '', 'json': False,
               **args}
    return [sys.executable, '-c', code, json.dumps(options), *ros_args]


def start(command: list[str]) -> subprocess.Popen:
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))


def wait_for_line(proc: subprocess.Popen, text: str, timeout: float) -> Lines:
    """Until a stdout line of ``proc`` contains ``text``; the lines read (``.seen``)."""
    if not hasattr(proc, 'lines'):
        proc.lines = Lines(proc.stdout)
    if proc.lines.wait_for(text, timeout) is not None:
        return proc.lines
    proc.kill()
    out, err = proc.communicate()
    pytest.fail(f'no {text!r} within {timeout} s:\n{"".join(proc.lines.seen)}'
                f'{proc.lines.leftover()}{out}\n{err}')


def node_log(suite, name: str = 'repeatability_trial') -> str:
    return suite.log_tail(name, lines=10000)


def test_echo_repeatability_shows_every_cycle_of_a_running_trial(ros, trial_data):
    echo = subprocess.Popen(cli_command('echo', 'repeatability', '--json', '--timeout', '60'),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))
    try:     # the echo subscribes before cycle 1 (it is latched, depth 1: cycle 1 once matched)
        assert wait_subscribed(ros, '/repeatability', 'cobot_calib_echo', 60.0)
        trial = cli('trial', '--cycles', str(CYCLES), '--json', timeout=120)
        assert trial.returncode == 0, trial.stderr
        result = json.loads(trial.stdout)
        echoed_id = result['trial_id']
        # every reading as it is measured (progress on stderr beside --json), in order
        readings = [line.split(':')[0].strip() for line in trial.stderr.splitlines()
                    if line.startswith('  cycle ')]
        assert readings == [f'cycle {c}/{CYCLES} P{i}' for c in range(1, CYCLES + 1)
                            for i in range(1, 6)]
        lines = wait_for_line(echo, f'"trial_id": "{echoed_id}", "method": "reference", '
                              '"axis": "z", '
                              f'"cycles_done": {CYCLES}, ', 30.0)
    finally:
        echo.terminate()
        out, _ = echo.communicate(timeout=10)
    printed = lines.seen + (lines.leftover() + out).splitlines()
    updates = [json.loads(line) for line in printed if line.startswith('{')]
    echoed = [u for u in updates if u['trial_id'] == echoed_id]
    assert [u['cycles_done'] for u in echoed] == list(range(1, CYCLES + 1))
    last = echoed[-1]
    assert last['method'] == 'reference' and last['axis'] == 'z'
    assert last['rp_all_mm'] == pytest.approx(result['rp_all_mm'])
    assert math.isnan(echoed[0]['rp_all'])          # one cycle: no sigma yet (eq 12, n - 1)
    low, high = reference_rp_all_band(CYCLES)
    assert low < last['rp_all'] < high, (low, high)
    assert last['rp_all'] == pytest.approx(last['rp_all_mm'] * 1e-3)   # SI on the wire
    stored = TrialStore(trial_data).load(echoed_id)
    assert stored.meta['status'] == 'done' and np.all(np.isfinite(stored.distances))
    retries = {'capture_joints': result['capture_retries'],
               'probe_average': result['probe_retries']}
    assert stored.meta['retries'] == retries          # what the client heard is what is stored
    assert np.all(np.abs(stored.distances - 1.2e-3) < 0.25e-3)       # F_i: mid-range


def reference_rp_all_band(cycles: int, draws: int = 20000) -> tuple[float, float]:
    """The central 99.8 % of a reference trial's RP_all [m] over ``cycles`` cycles, drawn from
    the cell's repeatability sigma at each marker (the mock's noise model, as
    test/core/repeatability/test_trial.py uses it): readings d_i + sigma_i N(0, 1)."""
    sim = load_simulation(paths.cell_file('sawyer_close'))
    sigma = np.array([sim.repeatability_sigma_at(p) for p in sim.world.true_points_base()])
    rng = np.random.default_rng(0)
    rp_all = [point_statistics(1.2e-3 + sigma[:, None] * rng.standard_normal(
        (len(sigma), cycles))).rp_all for _ in range(draws)]
    return tuple(np.quantile(rp_all, [0.001, 0.999]))


def test_a_canceled_trial_resumes_where_it_stopped(ros, trial_data, suite):
    client = ActionClient(ros, RunTrial, 'run_trial')
    ex = ros.executor_for_tests
    assert spin_until(ros, client.server_is_ready, 10.0, ex)
    readings = set()                # (cycle, point): feedback also repeats as a heartbeat
    send = client.send_goal_async(
        RunTrial.Goal(trial_id='resumed', method='rigid', cycles=3),
        feedback_callback=lambda fb: fb.feedback.point_name and readings.add(
            (fb.feedback.cycle, fb.feedback.point_index)))
    assert spin_until(ros, send.done, 10.0, ex)
    handle = send.result()
    assert spin_until(ros, lambda: len(readings) >= 7, 60.0, ex)
    cancel = handle.cancel_goal_async()
    assert spin_until(ros, cancel.done, 10.0, ex)
    outcome = handle.get_result_async()
    assert spin_until(ros, outcome.done, 30.0, ex)
    stopped = outcome.result().result
    assert stopped.error_code == RunTrial.Result.CANCELED and 'resume' in stopped.message
    assert (stopped.statistics.method, stopped.statistics.cycles_total) == ('rigid', 3)
    half = TrialStore(trial_data).load('resumed')
    assert half.meta['status'] == 'aborted' and half.resume is not None
    for goal, differ in ((RunTrial.Goal(trial_id='resumed', method='reference'),
                          'method reference (stored: rigid)'),
                         (RunTrial.Goal(trial_id='resumed', cycles=30),
                          'cycles 30 (stored: 3)')):
        _, refused = run_action(ros, client, goal, 30.0, executor=ex)
        assert refused.error_code == RunTrial.Result.INVALID_GOAL and differ in refused.message
    client.destroy()
    resumed = subprocess.run(trial_command(trial_id='resumed'), capture_output=True,
                             text=True, timeout=120, env=dict(os.environ))
    assert resumed.returncode == 0, resumed.stderr
    cycle = half.resume[0] + 1
    assert (f'resuming trial resumed: rigid, z axis, 3 cycles, from cycle {cycle}'
            in resumed.stdout)
    assert '(rigid, z axis)' in resumed.stdout and 'reference' not in resumed.stdout
    full = TrialStore(trial_data).load('resumed')
    assert full.meta['status'] == 'done' and np.all(np.isfinite(full.distances))
    kept = slice(0, half.resume[0])                  # complete cycles are kept as they were
    np.testing.assert_array_equal(full.distances[:, kept], half.distances[:, kept])
    log = node_log(suite)
    for line in ('trial resumed (rigid, z axis, 3 cycles): start',
                 'trial resumed (rigid, z axis, 3 cycles): canceled in cycle',
                 f'trial resumed (rigid, z axis, 3 cycles): resume at cycle {cycle} ',
                 'trial resumed (rigid, z axis, 3 cycles): done, 3 cycles'):
        assert line in log


@pytest.mark.parametrize('goal, message', [
    (dict(method='four_point'), "unknown method 'four_point'"),
    (dict(method='landmark_icp'), "unknown method 'landmark_icp'"),
    (dict(axis='w'), "unknown axis 'w'"),
    (dict(cycles=1), 'cycles must be 2..10000'),
    (dict(cycles=10001), 'cycles must be 2..10000'),
    (dict(trial_id='../escape'), 'id must match')])
def test_bad_trial_goals_are_rejected_and_the_node_logs_why(ros, suite, goal, message):
    client = ActionClient(ros, RunTrial, 'run_trial')
    with pytest.raises(CallError, match='rejected'):
        run_action(ros, client, RunTrial.Goal(**goal), 30.0, executor=ros.executor_for_tests)
    client.destroy()
    deadline = time.monotonic() + 5.0                   # until the log line is in the file
    while message not in _last_rejection(suite) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert message in _last_rejection(suite)


def _last_rejection(suite) -> str:
    lines = [line for line in node_log(suite).splitlines() if 'run_trial goal rejected: ' in line]
    return lines[-1] if lines else ''


def test_a_goal_for_another_layout_ends_with_a_reason(ros):
    client = ActionClient(ros, RunTrial, 'run_trial')
    _, result = run_action(ros, client, RunTrial.Goal(layout='wide'), 30.0,
                           executor=ros.executor_for_tests)
    client.destroy()
    assert result.error_code == RunTrial.Result.INVALID_GOAL
    assert 'layout' in result.message and 'layout:=wide' in result.message


@pytest.mark.parametrize('options, message', [
    (['--cycles', '-1'], 'cycles must be 2..10000'),
    (['--cycles', '1'], 'cycles must be 2..10000'),
    (['--cycles', '10001'], 'cycles must be 2..10000'),
    (['--method', 'landmark_icp'], "unknown method 'landmark_icp'; use one of reference,"),
    (['--trial-id', '../escape'], 'id must match')])
def test_the_trial_cli_refuses_a_bad_request_in_one_line(domain_id, options, message):
    """Checked before any ROS call: no suite needed, no traceback, exit code 2."""
    done = cli('trial', *options, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert done.stderr.startswith('trial rejected: ') and message in done.stderr


def test_ctrl_c_cancels_the_trial_and_says_how_to_resume_it(ros, trial_data):
    proc = start(cli_command('trial', '--cycles', '30'))
    started = wait_for_line(proc, ': reference, z axis, 30 cycles', 60.0).seen[-1]
    trial_id = re.search(r'trial (\S+): reference', started).group(1)
    wait_for_line(proc, '  cycle 1/30 P1: ', 60.0)     # taught, and the first reading printed
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert 'Traceback' not in out + err
    assert err.strip().splitlines() == [
        err.strip()], 'one line: stopped, and how to resume'
    assert f'trial {trial_id} stopped in cycle ' in err
    assert err.strip().endswith(f'resume it with: cobot-calib trial --trial-id {trial_id}')
    stored = TrialStore(trial_data).load(trial_id)
    assert stored.meta['status'] == 'aborted' and stored.resume is not None


def test_trial_health_is_on_diagnostics(ros):
    """OK running with cycle figures, OK idle after the end, WARN after a failed trial."""
    seen = []
    sub = ros.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda msg: seen.extend(s for s in msg.status if s.name == HEALTH), 10)
    client = ActionClient(ros, RunTrial, 'run_trial')
    ex = ros.executor_for_tests
    try:
        _, done = run_action(ros, client, RunTrial.Goal(trial_id='health', cycles=3), 120.0,
                             executor=ex)
        assert done.error_code == RunTrial.Result.SUCCESS, done.message
        running = [s for s in seen if s.message.startswith('running trial health: ')]
        assert running and all(s.level == DiagnosticStatus.OK for s in running)
        figures = {v.key: v.value for v in running[-1].values}
        assert figures['trial_id'] == 'health' and figures['cycles_total'] == '3'
        assert spin_until(ros, lambda: seen[-1].message.startswith('idle; trial health done'),
                          5.0, ex)
        assert seen[-1].level == DiagnosticStatus.OK
        # the node's retry counts since its start: at least this goal's
        idle = {v.key: v.value for v in seen[-1].values}
        assert int(idle['capture_retries']) >= done.capture_retries
        assert int(idle['probe_retries']) >= done.probe_retries
        run_action(ros, client, RunTrial.Goal(layout='wide'), 30.0, executor=ex)
        assert spin_until(ros, lambda: seen[-1].level == DiagnosticStatus.WARN, 5.0, ex)
        assert 'failed' in seen[-1].message and 'layout' in seen[-1].message
    finally:
        client.destroy()
        ros.destroy_subscription(sub)


SHORT_LEASE = Path(__file__).with_name('fastdds_short_lease.xml')


@dataclass
class _OnTheSuitesRobot(launcher.NodeSpec):
    """A second repeatability_trial in its own namespace, using the suite's robot and probe."""

    def command(self) -> list[str]:
        names = ['capture_joints', 'probe/average', 'mock_robot/hand_guide',
                 *(f'move_to/_action/{part}' for part in (
                     'send_goal', 'cancel_goal', 'get_result', 'feedback', 'status'))]
        # an action name is not remapped as a whole here: its services and topics are
        return super().command() + [a for n in names for a in ('-r', f'{n}:=/{n}')]


def test_the_client_gives_up_on_a_stalled_or_restarted_trial_node(ros, tmp_path):
    """No feedback for --stall-timeout s (the node frozen: SIGSTOP), or the node killed and
    started again: a clear message and exit 1, not an hour's wait; the frozen node, woken,
    answers a cancel and the trial is stored aborted, resumable.

    The node is frozen only until the client gives up (6 s without feedback, then 5 s for the
    cancel: about 11 s), well inside its lease (SHORT_LEASE, 30 s): a freeze longer than the
    lease made its peers drop it, and a cancel sent while they found it again after SIGCONT
    could go unanswered (a 12 s lease, outlasted by the freeze on a loaded machine)."""
    cell = str(paths.cell_file('sawyer_close'))
    nodes = launcher.Suite(tmp_path / 'logs')
    nodes.start([_OnTheSuitesRobot('repeatability_trial', {'cell_file': cell,
                                                           'data_dir': str(tmp_path)},
                                   namespace='doomed')],
                env=dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(SHORT_LEASE)))
    key = 'doomed.repeatability_trial'
    ros_args = ('--ros-args', '-r', '__ns:=/doomed')
    try:
        proc = start(trial_command(ros_args, cycles=30, stall_timeout=6.0))
        seen = wait_for_line(proc, 'reference: cycle 2/30', 60.0).seen     # readings flow
        doomed = next(re.match(r'trial (\S+): reference', line).group(1) for line in seen
                      if re.match(r'trial (\S+): reference', line))
        nodes.processes[key].send_signal(signal.SIGSTOP)
        errors = Lines(proc.stderr)
        gave_up = errors.wait_for('not canceled', 60.0)
        nodes.processes[key].send_signal(signal.SIGCONT)      # at once: inside its lease
        out, err = proc.communicate(timeout=30)
        err = ''.join(errors.seen) + errors.leftover() + err
        assert gave_up is not None and proc.returncode == 1, err
        assert 'no feedback from repeatability_trial for 6 s' in err and 'Traceback' not in err
        assert f'trial {doomed} not canceled' in err and 'it may go on' in err    # it was frozen
        assert err.strip().endswith(f'resume it with: cobot-calib trial --trial-id {doomed}')
        # woken up, the node stops the trial: canceled now, or its own 5 s probe timeout ran
        # out while it was frozen
        call(ros, CancelGoal, '/doomed/run_trial/_action/cancel_goal', timeout=15.0)
        assert wait_goals_ended(ros, '/doomed/run_trial', 30.0)
        assert TrialStore(tmp_path).load(doomed).meta['status'] == 'aborted'
        proc = start(trial_command(ros_args, trial_id=doomed))
        wait_for_line(proc, f'resuming trial {doomed}: reference, z axis, 30 cycles', 60.0)
        # killed and started again, as `cobot-calib up` does: the new instance on the graph
        # tells the client the goal is lost (the killed one stays there for its lease)
        nodes.processes[key].kill()
        nodes.processes[key].wait()
        nodes.restart(key)
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 1, err
        assert 'the repeatability_trial node restarted: goal lost' in err, err
        assert 'Traceback' not in err
        assert err.strip().endswith(f'resume it with: cobot-calib trial --trial-id {doomed}')
    finally:
        nodes.stop()
        assert wait_goals_ended(ros, '/move_to', 30.0)    # the move the trial was on has ended


def test_repeatability_is_republished_when_the_node_restarts(ros, tmp_path):
    """The latest trial's statistics (done or not), as user_frame's latest calibration is."""
    store, names = TrialStore(tmp_path), load_cell(paths.cell_file('sawyer_close')).point_names
    older = _stored_trial(store, 'older', names, cycles_total=4, measured=2)
    replay = launcher.NodeSpec('repeatability_trial',
                               {'cell_file': str(paths.cell_file('sawyer_close')),
                                'data_dir': str(tmp_path)}, namespace='replay')
    first = _latched(ros, replay, tmp_path / 'logs1')
    assert (first.trial_id, first.method, first.cycles_done, first.cycles_total) == (
        'older', 'rigid', 2, 4)
    assert first.rp_all == pytest.approx(point_statistics(older).rp_all)
    newer = _stored_trial(store, 'newer', names, cycles_total=3, measured=3)
    second = _latched(ros, replay, tmp_path / 'logs2')
    assert (second.trial_id, second.cycles_done) == ('newer', 3)
    assert list(second.rp) == pytest.approx(point_statistics(newer).rp.tolist())


def test_a_suite_republishes_and_resumes_only_its_own_cell_s_trials(ros, tmp_path):
    """A data dir shared with another robot's cell: its newer trial is neither republished as
    this cell's latest nor resumed here (refused by name); a trial this cell made is."""
    store, names = TrialStore(tmp_path), load_cell(paths.cell_file('sawyer_close')).point_names
    _stored_trial(store, 'mine', names, cycles_total=4, measured=2,
                  made_by={'cell': 'replay', 'robot': 'sawyer'})
    _stored_trial(store, 'theirs', names, cycles_total=4, measured=1,
                  made_by={'cell': 'iiwa7_close', 'robot': 'iiwa7'})
    replay = launcher.NodeSpec('repeatability_trial',
                               {'cell_file': str(paths.cell_file('sawyer_close')),
                                'data_dir': str(tmp_path)}, namespace='replay')
    nodes, got = launcher.Suite(tmp_path / 'logs'), []
    nodes.start([replay])
    sub = ros.create_subscription(Repeatability, '/replay/repeatability', got.append,
                                  qos.LATCHED)
    client = ActionClient(ros, RunTrial, '/replay/run_trial')
    try:
        assert spin_until(ros, lambda: got, STARTUP_TIMEOUT, ros.executor_for_tests), \
            nodes.log_tail('replay.repeatability_trial')
        _, refused = run_action(ros, client, RunTrial.Goal(trial_id='theirs'), 60.0,
                                executor=ros.executor_for_tests)
    finally:
        client.destroy()
        ros.destroy_subscription(sub)
        assert nodes.stop(STOP_TIMEOUT) == {'replay.repeatability_trial': 0}
    assert [m.trial_id for m in got] == ['mine']
    assert refused.error_code == RunTrial.Result.INVALID_GOAL
    assert refused.message.startswith(
        "trial theirs is not this cell's: it was made in cell 'iiwa7_close' on the iiwa7; "
        "this is cell 'replay' on the sawyer"), refused.message
    assert store.load('theirs').meta['status'] == 'aborted'      # untouched


def _stored_trial(store: TrialStore, trial_id: str, names, cycles_total: int,
                  measured: int, made_by: dict | None = None) -> np.ndarray:
    """A rigid trial with ``measured`` cycles of readings; its distances [m]. ``made_by``:
    its cell and robot (none: a trial stored before trials named them)."""
    rng = np.random.default_rng(len(trial_id))
    store.create(trial_id, method='rigid', axis='z', layout='close', point_names=names,
                 cycles_total=cycles_total, extra=made_by)
    d = 1.2e-3 + rng.normal(0.0, 2e-5, (len(names), measured))
    for cycle in range(measured):
        for i in range(len(names)):
            store.append(trial_id, cycle, i, d[i, cycle])
    store.set_status(trial_id, 'done' if measured == cycles_total else 'aborted')
    return d


def _latched(ros, spec: launcher.NodeSpec, log_dir) -> Repeatability:
    """Start the node, take what it latched on /replay/repeatability, stop the node."""
    nodes, got = launcher.Suite(log_dir), []
    nodes.start([spec])
    sub = ros.create_subscription(Repeatability, '/replay/repeatability', got.append,
                                  qos.LATCHED)
    try:
        assert spin_until(ros, lambda: got, STARTUP_TIMEOUT, ros.executor_for_tests), \
            nodes.log_tail('replay.repeatability_trial')
    finally:
        ros.destroy_subscription(sub)
        assert nodes.stop(STOP_TIMEOUT) == {'replay.repeatability_trial': 0}
    return got[-1]


def test_a_landmark_multi_trial_runs_over_ros_with_its_calibration_time(ros, trial_data,
                                                                        suite):
    """Each cycle's frame from the wrist camera (18 views of the six fiducials through
    mock_camera and landmark_detector), then the probe pass; the stored calibration time is the
    robot time of those views (moves as mock_robot reports them, and the holds)."""
    client = ActionClient(ros, RunTrial, 'run_trial')
    try:
        _, result = run_action(ros, client, RunTrial.Goal(method='landmark_multi', cycles=2),
                               600.0, executor=ros.executor_for_tests)
    finally:
        client.destroy()
    assert result.error_code == RunTrial.Result.SUCCESS, result.message
    s = result.statistics
    assert s.method == 'landmark_multi' and s.cycles_done == 2
    # two cycles: RP is mostly the spread of two frames; the close layout's is ~0.1 mm
    assert 0.0 < s.rp_all < 0.5e-3
    meta = TrialStore(trial_data).load(result.trial_id).meta
    times = meta['calibration_s']
    assert len(times) == 2 and all(t is not None and t > 0 for t in times)
    assert result.calibration_seconds == pytest.approx(sum(times) / 2)
    # 18 holds of capture_duration and 18 moves of at least a few degrees each
    hold = float(suite.specs['repeatability_trial'].params['capture_duration'])
    assert result.calibration_seconds > 18 * hold
