"""Mock robot, joint_state_monitor and proximity_sensor across processes."""
import json
import math
import time

from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.msg import ProbeVoltage, ProximityReading
from cobot_calib_msgs.srv import AverageProximity, CaptureJoints, GetGroundTruth, HandGuide
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from cobot_calib_ros.ros import convert, qos
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import run_action, spin_until
from cobot_calib_ros.ros.time import now_ns, ns_to_stamp
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.core import frames
from cobot_calib_ros.paths import cell_file, DEFAULT_CELL
from rosutil import call, cli, true_gap

CELL = load_cell(cell_file(DEFAULT_CELL))


def _move(node, **goal_fields):
    client = ActionClient(node, MoveTo, 'move_to')
    try:
        _, result = run_action(node, client, MoveTo.Goal(**goal_fields), 30.0,
                               executor=node.executor_for_tests)
        return result
    finally:
        client.destroy()


def test_echo_once_prints_a_joint_state(ros):
    out = cli('echo', 'joint_states', '--once', '--json')
    assert out.returncode == 0, out.stderr
    msg = json.loads(out.stdout)
    assert msg['name'] == [f'right_j{i}' for i in range(7)]
    assert len(msg['position']) == 7 and all(math.isfinite(p) for p in msg['position'])


def test_list_shows_every_node_and_interface(ros):
    out = cli('list', '--json')
    assert out.returncode == 0, out.stderr
    g = json.loads(out.stdout)
    assert {'/mock_robot', '/joint_state_monitor', '/proximity_sensor', '/user_frame_solver',
            '/iso/proximity_sensor'} <= set(g['nodes'])
    assert g['topics']['/joint_states'] == ['sensor_msgs/msg/JointState']
    assert g['services']['/capture_joints'] == ['cobot_calib_msgs/srv/CaptureJoints']
    assert g['actions']['/move_to'] == ['cobot_calib_msgs/action/MoveTo']


def test_capture_at_home_matches_commanded_joints_and_encoder_noise(ros):
    res = call(ros, CaptureJoints, 'capture_joints', duration=0.5)
    assert res.error_code == CaptureJoints.Response.SUCCESS, res.message
    assert res.sample_count >= 250                      # half the 1 kHz samples at least
    np.testing.assert_allclose(res.position, CELL.home, atol=5 * 2e-6 / np.sqrt(250))
    assert all(1e-6 < s < 4e-6 for s in res.std)        # encoder noise sigma 2e-6 rad


def test_capture_refuses_while_the_arm_moves(ros):
    client = ActionClient(ros, MoveTo, 'move_to')
    ex = ros.executor_for_tests
    spin_until(ros, client.server_is_ready, 10.0, ex)
    target = CELL.home + np.array([0.6, 0, 0, 0, 0, 0, 0])
    # 0.6 rad at 0.025 rad/s: 24 s of robot time, 1.2 s at the session suite's time_scale
    send = client.send_goal_async(MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS,
                                              positions=target.tolist(), speed_scale=0.025))
    spin_until(ros, send.done, 10.0, ex)
    res = call(ros, CaptureJoints, 'capture_joints', duration=0.2)
    assert res.error_code == CaptureJoints.Response.MOVING, res.message
    assert 'moving' in res.message and 'right_j0' in res.message
    result = send.result().get_result_async()
    spin_until(ros, result.done, 20.0, ex)
    back = _move(ros, target_type=MoveTo.Goal.TARGET_JOINTS, positions=CELL.home.tolist())
    assert back.error_code == MoveTo.Result.SUCCESS


def test_capture_rejects_a_bad_duration(ros):
    res = call(ros, CaptureJoints, 'capture_joints', duration=-1.0)
    assert res.error_code == CaptureJoints.Response.BAD_REQUEST
    assert 'duration' in res.message


def test_capture_over_a_given_start_a_past_window_or_one_too_far_ahead(ros):
    """CaptureJoints.start: a window already past is averaged from the buffer; a start further
    ahead than the buffer is refused saying what to give (replay --recapture: the recorded
    window's means to the bit, test_replay_check)."""
    past = now_ns(ros) - 2 * 10**9
    res = call(ros, CaptureJoints, 'capture_joints', duration=0.5, start=ns_to_stamp(past))
    # the arm may have been moving then (the test before moves it): MOVING is that window's
    # verdict too; either way its samples, from the buffer
    assert res.error_code in (CaptureJoints.Response.SUCCESS,
                              CaptureJoints.Response.MOVING), res.message
    assert res.sample_count > 0
    ahead = call(ros, CaptureJoints, 'capture_joints', duration=0.5,
                 start=ns_to_stamp(now_ns(ros) + 3600 * 10**9))
    assert ahead.error_code == CaptureJoints.Response.BAD_REQUEST
    assert 'ahead of this node' in ahead.message and 'zero' in ahead.message


def _monitor_counts(ros, done=lambda counts: True, timeout=10.0) -> dict:
    """The monitor's latest /diagnostics counters, once `done(counts)` holds (or timeout)."""
    latest = {}

    def on_diag(msg):
        for s in msg.status:
            if 'joint_state_monitor' in s.name:
                latest.clear()
                latest.update({kv.key: int(kv.value) for kv in s.values})
    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    spin_until(ros, lambda: bool(latest) and done(latest), timeout, ros.executor_for_tests)
    ros.destroy_subscription(sub)
    return latest


def test_malformed_joint_states_are_dropped_and_counted(ros):
    before = _monitor_counts(ros)
    pub = ros.create_publisher(JointState, 'joint_states', 10)
    names = [f'right_j{i}' for i in range(7)]
    bad = [JointState(name=names, position=[0.0] * 6 + [math.nan]),
           JointState(name=names, position=[0.0] * 6),
           JointState(name=names[:6] + ['elbow'], position=[0.0] * 7)]
    spin_until(ros, lambda: pub.get_subscription_count() > 0, 5.0, ros.executor_for_tests)
    spin_until(ros, lambda: False, 1.0, ros.executor_for_tests)   # let the reader match us too
    for msg in bad * 3:
        pub.publish(msg)
    reasons = ('non_finite', 'length_mismatch', 'unknown_joints')
    after = _monitor_counts(ros, lambda c: all(
        c[f'dropped_{r}'] - before[f'dropped_{r}'] >= 3 for r in reasons))
    ros.destroy_publisher(pub)
    for reason in reasons:
        assert after[f'dropped_{reason}'] - before[f'dropped_{reason}'] == 3, reason
    res = call(ros, CaptureJoints, 'capture_joints', duration=0.2)
    assert res.error_code == CaptureJoints.Response.SUCCESS     # the good stream is untouched


@pytest.mark.parametrize('voltage, status', [
    (-0.5, ProximityReading.STATUS_BELOW_RANGE), (-25.0, ProximityReading.STATUS_ABOVE_RANGE),
    (math.nan, ProximityReading.STATUS_INVALID), (-9.45, ProximityReading.STATUS_OK)])
def test_probe_voltage_range_check(ros, voltage, status):
    got = []
    sub = ros.create_subscription(ProximityReading, '/iso/probe/distance', got.append,
                                  qos_profile_sensor_data)
    pub = ros.create_publisher(ProbeVoltage, '/iso/probe/voltage', qos_profile_sensor_data)
    ex = ros.executor_for_tests
    spin_until(ros, lambda: pub.get_subscription_count() > 0 and sub.get_publisher_count() > 0,
               5.0, ex)
    deadline = time.monotonic() + 5.0
    while not got and time.monotonic() < deadline:
        pub.publish(ProbeVoltage(voltage=voltage))
        spin_until(ros, lambda: bool(got), 0.2, ex)
    ros.destroy_subscription(sub)
    ros.destroy_publisher(pub)
    assert got, 'no ProximityReading came back'
    assert got[0].status == status
    if status == ProximityReading.STATUS_OK:
        assert got[0].distance == pytest.approx(0.0012, abs=1e-9)   # -9.45 V in the table
    else:
        assert math.isnan(got[0].distance)


def test_probe_average_counts_a_late_burst_stamped_inside_its_window(ros):
    """issue 31: a starved probe publisher catches up in a burst of readings stamped when they
    were taken (mock_robot's sample clock); an 80 ms window that passed before they came still
    averages every one of them (was: "no probe readings in 0.080 s", history 5 kept 5)."""
    pub = ros.create_publisher(ProbeVoltage, '/iso/probe/voltage', qos.PROBE_READINGS)
    client = ros.create_client(AverageProximity, '/iso/probe/average')
    ex = ros.executor_for_tests
    try:
        spin_until(ros, lambda: pub.get_subscription_count() > 0 and client.service_is_ready(),
                   10.0, ex)
        asked_ns = now_ns(ros)
        future = client.call_async(AverageProximity.Request(duration=0.08))
        spin_until(ros, future.done, 0.3, ex)       # the window passes with nothing published
        period_ns = 2_000_000
        for k in range(-50, 200):                   # taken from 0.1 s before to 0.4 s after
            pub.publish(ProbeVoltage(header=Header(stamp=ns_to_stamp(asked_ns + k * period_ns)),
                                     voltage=-9.45))
        spin_until(ros, future.done, 10.0, ex)
    finally:
        ros.destroy_client(client)
        ros.destroy_publisher(pub)
    res = future.result()
    assert res is not None and res.error_code == AverageProximity.Response.SUCCESS, res
    assert res.sample_count in (40, 41)             # 80 ms of 2 ms readings, both ends counted
    assert res.rejected_count == 0
    assert res.distance == pytest.approx(0.0012, abs=1e-9)     # -9.45 V in the table


def test_probe_above_a_marker_reads_the_true_gap(ros):
    """Send the tool 1.2 mm above P5's true top face; the probe must read about that."""
    truth = call(ros, GetGroundTruth, 'get_ground_truth')
    T_base_user = convert.transform_to_matrix(truth.user_frame)
    top = convert.points_to_array(truth.points_base)[truth.point_names.index('P5')]
    T = frames.make_transform(cellmod.tool_down_orientation(T_base_user),
                              top + T_base_user[:3, 2] * 0.0012)
    moved = _move(ros, target_type=MoveTo.Goal.TARGET_POSE, pose=convert.matrix_to_pose(T))
    assert moved.error_code == MoveTo.Result.SUCCESS, moved.message
    res = call(ros, AverageProximity, 'probe/average', duration=0.3)
    assert res.error_code == AverageProximity.Response.SUCCESS, res.message
    # the nominal model and tool misplace the real tip (kinematic errors ~0.1 mm, the tool's
    # 0.25 mm): the probe reads where the real tip is
    assert res.distance == pytest.approx(true_gap(truth, moved.positions, 'P5'), abs=1e-4)
    assert res.std < 2e-6                                # 4 mV noise at 8 V/mm = 0.5 um


def test_move_to_bad_targets_are_refused_with_a_reason(ros):
    nan = _move(ros, target_type=MoveTo.Goal.TARGET_JOINTS, positions=[math.nan] * 7)
    assert nan.error_code == MoveTo.Result.INVALID_TARGET and 'finite' in nan.message
    touch = MoveTo.Goal.TARGET_POSE + 1                # what TARGET_TOUCH was: no move kind
    old = _move(ros, target_type=touch)
    assert old.error_code == MoveTo.Result.INVALID_TARGET and 'hand_guide' in old.message
    unknown = call(ros, HandGuide, 'mock_robot/hand_guide', point_name='P9')
    assert unknown.error_code == HandGuide.Response.INVALID_TARGET and 'P1' in unknown.message
    far = frames.make_transform(np.eye(3), [3.0, 0.0, 0.0])
    out = _move(ros, target_type=MoveTo.Goal.TARGET_POSE, pose=convert.matrix_to_pose(far))
    assert out.error_code == MoveTo.Result.UNREACHABLE
