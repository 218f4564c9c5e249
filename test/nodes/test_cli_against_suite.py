"""`cobot-calib` call / echo / list / up as users type them, against the running suite."""
import json
import math
import os
import signal
import subprocess
import time

import pytest

from rosutil import cli, cli_command, STARTUP_TIMEOUT, STOP_TIMEOUT

from cobot_calib_ros.core.sensors.joint_buffer import HOLD_EXTENSIONS

SUITE_NODES = {'/mock_robot', '/joint_state_monitor', '/proximity_sensor',
               '/user_frame_solver', '/repeatability_trial'}
CAPTURE = 'cobot_calib_msgs/srv/CaptureJoints'
BAD_REQUEST = 3                 # CaptureJoints.Response.BAD_REQUEST
# A pure translation by (0.5, 0.1, 0.05) m: user (1, 2, 3) is base (1.5, 2.1, 3.05).
SQUARE = ('[{x: 0.0, y: 0.0, z: 0.0}, {x: 0.2, y: 0.0, z: 0.0}, {x: 0.2, y: 0.15, z: 0.0}, '
          '{x: 0.0, y: 0.15, z: 0.0}]')
SHIFTED = ('[{x: 0.5, y: 0.1, z: 0.05}, {x: 0.7, y: 0.1, z: 0.05}, {x: 0.7, y: 0.25, z: 0.05}, '
           '{x: 0.5, y: 0.25, z: 0.05}]')


def _at_once(*commands, timeout=60.0) -> list[subprocess.CompletedProcess]:
    """Run several `cobot-calib ARGS` at the same time (each discovers on its own)."""
    running = [subprocess.Popen(cli_command(*args), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, env=dict(os.environ))
               for args in commands]
    done = []
    for args, p in zip(commands, running):
        out, err = p.communicate(timeout=timeout)
        done.append(subprocess.CompletedProcess(args, p.returncode, out, err))
    return done


def _json(out: subprocess.CompletedProcess) -> dict:
    assert out.returncode == 0, f'exit {out.returncode}: {out.stderr}'
    return json.loads(out.stdout)


def _answered(out: subprocess.CompletedProcess) -> dict:
    """The response of a call that may be refused: printed all the same, and a refusal (a
    non-zero error_code) exits 1 saying so (issue 23.8)."""
    res = json.loads(out.stdout)
    refused = res.get('error_code', 0) != 0
    assert out.returncode == (1 if refused else 0), f'exit {out.returncode}: {out.stderr}'
    assert ('answered error_code' in out.stderr) == refused, out.stderr
    return res


@pytest.fixture(scope='module')
def translation_id(ros):
    """A stored calibration that only shifts by (0.5, 0.1, 0.05) m, made through the CLI."""
    res = _json(cli('call', 'calibrate_user_frame',
                    f'{{method: rigid, points_user: {SQUARE}, points_base: {SHIFTED}}}', '--json'))
    assert res['error_code'] == 0, res['message']
    return res['calibration']['id']


def test_int_and_exponent_durations_do_not_abort_the_client(ros):
    """What the node receives: `0.2e0` and `1` as 0.2 s and 1 s, `1e9` as 1e9 s (was SIGABRT
    in the rosidl C code). The parsing itself is test/cli/test_fields.py's, without a stream."""
    big, big_float = _at_once(['call', 'capture_joints', '{duration: 1e9}', '--json'],
                              ['call', 'capture_joints', '{duration: 1.0e9}', '--json'])
    for out in (big, big_float):                 # refused by the node, which names the value
        res = _answered(out)
        assert out.returncode == 1
        assert res['error_code'] == BAD_REQUEST and '1000000000.0 s' in res['message']
    # one at a time: a starved stream is not absorbed here (test_a_starved_stream_...)
    short = _json(cli('call', 'capture_joints', '{duration: 0.2e0}', '--json'))
    assert short['error_code'] == 0, short['message']
    # success needs min_sample_fraction (0.5) x 1 kHz x the window: 100 samples for 0.2 s,
    # and a window of 1 ns (or 0.2 ms) would hold at most one
    # (a loaded machine's thinned stream makes the hold go on by whole windows: at most
    # 1 + HOLD_EXTENSIONS of them)
    longest = 1 + HOLD_EXTENSIONS
    assert short['sample_count'] >= 100 and short['window'] <= 0.2 * longest
    whole = _json(cli('call', 'capture_joints', '{duration: 1}', '--json'))
    assert whole['error_code'] == 0, whole['message']
    assert whole['sample_count'] >= 500 and whole['window'] <= longest  # 1 is 1 s, not 1 ns


def test_a_starved_stream_is_no_data_naming_the_window(ros, tmp_path):
    """A joint_state_monitor whose joint_states stop: NO_DATA says how many samples came in
    which window and what to check; nothing is averaged from too few samples."""
    from cobot_calib_msgs.srv import CaptureJoints
    from cobot_calib_ros.api import launcher
    from rosutil import call
    starved = launcher.Suite(tmp_path / 'logs')
    starved.start([launcher.NodeSpec('joint_state_monitor', namespace='starved')])
    try:
        # not asked again: each copy would wait out the first-sample wait before the stop
        res = call(ros, CaptureJoints, '/starved/capture_joints', timeout=30.0, resend=False,
                   duration=0.2)
    finally:
        assert starved.stop(STOP_TIMEOUT) == {'starved.joint_state_monitor': 0}
    assert res.error_code == CaptureJoints.Response.NO_DATA
    assert res.message == ('only 0 joint_states samples in 0.200 s (need 100); is the robot '
                           'driver (mock_robot) publishing joint_states?')
    assert res.sample_count == 0 and all(math.isnan(v) for v in res.position)


def test_a_thinned_stream_makes_the_hold_go_on_until_it_has_its_samples(ros, tmp_path):
    """A driver's stream arriving at a quarter of its rate (a loaded machine's 1 kHz timer
    missing ticks): the hold goes on by whole windows until it has the samples it needs, the
    verdict an idle machine gives, instead of NO_DATA."""
    from cobot_calib_msgs.srv import CaptureJoints
    from sensor_msgs.msg import JointState
    from cobot_calib_ros.api import launcher
    from rosutil import call
    publisher = ros.create_publisher(JointState, '/thinned/joint_states', 100)
    started, sent = time.monotonic(), 0

    def tick():
        # 250 Hz on average, however late this test's own timer runs: once, at a load that
        # doubled every test's CPU, a plain 250 Hz timer sent 74 a second, and the node
        # rightly said too few
        nonlocal sent
        while sent < int((time.monotonic() - started) * 250):
            message = JointState(name=['j1', 'j2'], position=[0.1, -0.2])
            message.header.stamp = ros.get_clock().now().to_msg()
            publisher.publish(message)
            sent += 1
    timer = ros.create_timer(0.004, tick)          # 250 Hz against the expected 1 kHz
    thinned = launcher.Suite(tmp_path / 'logs')
    thinned.start([launcher.NodeSpec('joint_state_monitor', namespace='thinned')])
    try:
        res = call(ros, CaptureJoints, '/thinned/capture_joints', timeout=30.0,
                   ready_timeout=STARTUP_TIMEOUT, duration=0.2)
    finally:
        ros.destroy_timer(timer)
        ros.destroy_publisher(publisher)
        assert thinned.stop(STOP_TIMEOUT) == {'thinned.joint_state_monitor': 0}
    assert res.error_code == 0, res.message      # 100 samples needed, ~50 come per window
    assert res.sample_count >= 100 and 0.2 < res.window <= 0.2 * (1 + HOLD_EXTENSIONS)
    assert res.position == pytest.approx([0.1, -0.2])


def test_int_points_are_converted_as_floats(ros, translation_id):
    res = _json(cli('call', 'user_to_robot',
                    f'{{calibration_id: {translation_id}, points: [{{x: 1, y: 2, z: 3}}]}}',
                    '--json'))
    assert res['error_code'] == 0, res['message']
    point = res['points'][0]
    assert [point['x'], point['y'], point['z']] == pytest.approx([1.5, 2.1, 3.05], abs=1e-9)


def test_nan_reaches_the_node_as_nan(ros, translation_id):
    res = _answered(cli('call', 'user_to_robot',
                        f'{{calibration_id: {translation_id}, points: [{{x: nan, y: 2, z: 3}}]}}',
                        '--json'))
    assert res['error_code'] == 2 and 'NaN' in res['message']      # INVALID_INPUT


def test_a_value_that_does_not_fit_names_the_field(ros):
    out = cli('call', 'user_to_robot', '{points: [{x: abc, y: 2, z: 3}]}')
    assert out.returncode == 2
    assert out.stderr == "bad request: points[0].x: expected a float, got 'abc'\n"


def test_call_takes_service_type_values_as_ros2_does(ros):
    forms = (['/capture_joints', CAPTURE, '{duration: 0.5}'],
             ['capture_joints', '--type', CAPTURE, '{duration: 0.5}'],
             ['capture_joints', 'cobot_calib_msgs/CaptureJoints'])       # default request
    for out in _at_once(*[['call', *form, '--json'] for form in forms]):
        assert 'sample_count' in _answered(out)      # answered (the capture may say no_data)


def test_a_wrong_type_is_named_not_blamed_on_the_suite(ros):
    out = cli('call', 'capture_joints', '{duration: 0.5}',
              '--type', 'cobot_calib_msgs/srv/AverageProximity')
    assert out.returncode == 2
    assert out.stderr.startswith('type cobot_calib_msgs/srv/AverageProximity does not match '
                                 'the advertised type(s) of /capture_joints: ' + CAPTURE)
    assert 'suite up' not in out.stderr


def test_list_finds_every_node_each_time(ros):
    for out in _at_once(*[['list', '--json']] * 3):
        assert SUITE_NODES | {'/iso/proximity_sensor'} <= set(_json(out)['nodes'])


def test_echo_once_matches_a_best_effort_publisher(ros):
    for out in _at_once(*[['echo', 'probe/voltage', '--once', '--json']] * 3):
        assert math.isfinite(_json(out)['voltage'])


def test_up_refuses_a_second_suite_on_the_same_domain(ros, domain_id):
    up = subprocess.Popen(cli_command('up'), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True, env=dict(os.environ))
    try:
        out, err = up.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        up.send_signal(signal.SIGINT)                  # it started a second suite: stop it
        out, err = up.communicate(timeout=20)
        pytest.fail(f'up started a second suite:\n{out}{err}')
    assert up.returncode == 1, out + err
    assert f'already runs on ROS_DOMAIN_ID={domain_id}' in err and '/mock_robot' in err
    assert '--force' in err and not out
