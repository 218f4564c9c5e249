"""run_trial and the live repeatability topic, across processes, through the CLI users type."""
import json
import math
import os
import subprocess
import time

from cobot_calib_msgs.action import RunTrial
import numpy as np
import pytest
from rclpy.action import ActionClient

from cobot_calib_ros.api.client import run_action, spin_until
from cobot_calib_ros.store.trials import TrialStore
from rosutil import cli, cli_command

CYCLES = 4


def test_echo_repeatability_shows_every_cycle_of_a_running_trial(ros, trial_data):
    echo = subprocess.Popen(cli_command('echo', 'repeatability', '--json', '--timeout', '60'),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))
    try:
        time.sleep(2.0)                              # the echo subscribes before cycle 1
        trial = cli('trial', '--cycles', str(CYCLES), '--trial-id', 'echoed', '--json',
                    timeout=120)
        assert trial.returncode == 0, trial.stderr
        result = json.loads(trial.stdout)
        time.sleep(0.5)
    finally:
        echo.terminate()
        out, _ = echo.communicate(timeout=10)
    updates = [json.loads(line) for line in out.splitlines() if line.startswith('{')]
    echoed = [u for u in updates if u['trial_id'] == 'echoed']
    assert [u['cycles_done'] for u in echoed] == list(range(1, CYCLES + 1))
    last = echoed[-1]
    assert last['method'] == 'reference' and last['axis'] == 'z'
    assert last['rp_all_mm'] == pytest.approx(result['rp_all_mm'])
    assert math.isnan(echoed[0]['rp_all'])          # one cycle: no sigma yet (eq 12, n - 1)
    # the mock's unidirectional repeatability is 0.03 mm per axis: RP about 0.08 mm
    assert 0.02 < last['rp_all_mm'] < 0.2
    assert last['rp_all'] == pytest.approx(last['rp_all_mm'] * 1e-3)   # SI on the wire
    stored = TrialStore(trial_data).load('echoed')
    assert stored.meta['status'] == 'done' and np.all(np.isfinite(stored.distances))
    assert np.all(np.abs(stored.distances - 1.2e-3) < 0.25e-3)       # F_i: mid-range


def test_a_canceled_trial_resumes_where_it_stopped(ros, trial_data):
    client = ActionClient(ros, RunTrial, 'run_trial')
    ex = ros.executor_for_tests
    assert spin_until(ros, client.server_is_ready, 10.0, ex)
    readings = []
    send = client.send_goal_async(
        RunTrial.Goal(trial_id='resumed', method='rigid', cycles=3),
        feedback_callback=lambda fb: readings.append(fb.feedback.point_index))
    assert spin_until(ros, send.done, 10.0, ex)
    handle = send.result()
    assert spin_until(ros, lambda: len(readings) >= 7, 60.0, ex)
    cancel = handle.cancel_goal_async()
    assert spin_until(ros, cancel.done, 10.0, ex)
    outcome = handle.get_result_async()
    assert spin_until(ros, outcome.done, 30.0, ex)
    stopped = outcome.result().result
    assert stopped.error_code == RunTrial.Result.CANCELED and 'resume' in stopped.message
    half = TrialStore(trial_data).load('resumed')
    assert half.meta['status'] == 'aborted' and half.resume is not None
    _, done = run_action(ros, client, RunTrial.Goal(trial_id='resumed'), 120.0, executor=ex)
    assert done.error_code == RunTrial.Result.SUCCESS, done.message
    full = TrialStore(trial_data).load('resumed')
    assert full.meta['status'] == 'done' and np.all(np.isfinite(full.distances))
    measured_before = np.isfinite(half.distances)
    np.testing.assert_array_equal(full.distances[measured_before],
                                  half.distances[measured_before])
    client.destroy()


@pytest.mark.parametrize('goal, message', [
    (dict(method='four_point'), 'unknown method'),
    (dict(axis='w'), 'unknown axis'),
    (dict(layout='wide'), 'layout'),
    (dict(trial_id='../escape'), 'id must match')])
def test_bad_trial_goals_are_refused_with_a_reason(ros, goal, message):
    client = ActionClient(ros, RunTrial, 'run_trial')
    _, result = run_action(ros, client, RunTrial.Goal(**goal), 30.0,
                           executor=ros.executor_for_tests)
    client.destroy()
    assert result.error_code == RunTrial.Result.INVALID_GOAL
    assert message in result.message
