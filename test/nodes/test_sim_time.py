"""ROS time: captures and probe averages with use_sim_time and a /clock at 2x and 0.5x.

A second mock robot, joint_state_monitor and proximity_sensor in the namespace /simtime all run
on simulated time, driven by a /clock published from this test (ros.sim_clock). Their windows
are in ROS time: a 0.5 s capture holds 0.5 s of stamps at either rate (a window in wall time
would hold 1.0 s at 2x and 0.25 s at 0.5x). The wall time a window takes and the samples it
holds depend on the machine's load: bench/bench_sim_time.py prints them.
"""
from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.msg import ProbeAverageMark
from cobot_calib_msgs.srv import AverageProximity, CaptureJoints, GetGroundTruth
import pytest
from sensor_msgs.msg import JointState

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import run_action, spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.ros import convert, marks
from cobot_calib_ros.ros.sim_clock import SimClock
from cobot_calib_ros.ros.time import ns_to_s, stamp_to_ns
from rosutil import call, STARTUP_TIMEOUT, STOP_TIMEOUT, true_gap

NS = 'simtime'


@pytest.fixture(scope='module')
def sim_clock(ros, tmp_path_factory):
    clock = SimClock(ros)
    sim = {'use_sim_time': 'true'}
    specs = [launcher.NodeSpec(n, dict(p, **sim), namespace=NS) for n, p in (
        ('mock_robot', {'time_scale': '0.2'}),
        # windows, not the stream's rate, are tested here: a starved stream is no NO_DATA
        ('joint_state_monitor', {'min_sample_fraction': '0.01'}),
        ('proximity_sensor', {}))]
    suite = launcher.Suite(tmp_path_factory.mktemp('simtime_logs'))
    suite.start(specs)
    services = {f'/{NS}/capture_joints', f'/{NS}/probe/average', f'/{NS}/get_ground_truth'}
    ready = spin_until(ros, lambda: services <= {n for n, _ in ros.get_service_names_and_types()},
                       STARTUP_TIMEOUT, ros.executor_for_tests)
    assert ready, '\n'.join(suite.log_tail(n) for n in suite.processes)
    yield clock
    codes = suite.stop(STOP_TIMEOUT)
    clock.stop()
    assert all(c == 0 for c in codes.values()), codes


def _capture(ros, duration):
    return call(ros, CaptureJoints, f'/{NS}/capture_joints', timeout=30.0, duration=duration)


def _wait_stamped_after(ros, sim_ns: int) -> None:
    """Until a /simtime/joint_states message stamped after ``sim_ns`` arrives."""
    got = []
    sub = ros.create_subscription(
        JointState, f'/{NS}/joint_states',
        lambda msg: got.append(stamp_to_ns(msg.header.stamp) > sim_ns), 100)
    try:
        assert spin_until(ros, lambda: any(got), 30.0, ros.executor_for_tests)
    finally:
        ros.destroy_subscription(sub)


@pytest.mark.parametrize('rate', [2.0, 0.5])
def test_a_capture_window_is_in_ros_time(ros, sim_clock, rate):
    sim_clock.rate = rate
    _wait_stamped_after(ros, sim_clock.sim_ns)    # joint_states on the clock at this rate
    _capture(ros, 0.1)       # the monitor's first samples on this clock
    res = _capture(ros, 0.5)
    assert res.error_code == CaptureJoints.Response.SUCCESS, res.message
    # 0.5 s of stamps (ROS time); a window in wall time would hold 1.0 s (2x) or 0.25 s
    # (0.5x). A loaded machine can starve the monitor of part of the window (one run: 0.09 s
    # of 2x stamps), which only shortens the span: each rate checks the side a wall-time
    # window would fail on
    assert res.sample_count >= 2
    if rate > 1.0:
        assert 0.0 < res.window <= 0.5 + 2e-3
    else:
        assert 0.3 < res.window <= 0.5 + 2e-3


@pytest.mark.parametrize('rate', [2.0, 0.5])
def test_a_probe_average_is_in_ros_time(ros, sim_clock, rate):
    sim_clock.rate = rate
    truth = call(ros, GetGroundTruth, f'/{NS}/get_ground_truth')
    T_base_user = convert.transform_to_matrix(truth.user_frame)
    top = convert.points_to_array(truth.points_base)[truth.point_names.index('P5')]
    target = frames.make_transform(tool_down_orientation(T_base_user),
                                   top + T_base_user[:3, 2] * 0.0012)
    client = ActionClient(ros, MoveTo, f'/{NS}/move_to')
    try:
        _, moved = run_action(ros, client, MoveTo.Goal(
            target_type=MoveTo.Goal.TARGET_POSE, pose=convert.matrix_to_pose(target)), 30.0,
            executor=ros.executor_for_tests)
    finally:
        client.destroy()
    assert moved.error_code == MoveTo.Result.SUCCESS, moved.message
    served = []         # proximity_sensor's mark of the average: its window's reading stamps
    sub = ros.create_subscription(ProbeAverageMark, f'/{NS}/{marks.PROBE_AVERAGES}',
                                  served.append, 10)
    try:
        assert spin_until(ros, lambda: sub.get_publisher_count() > 0, 30.0,
                          ros.executor_for_tests)
        res = call(ros, AverageProximity, f'/{NS}/probe/average', timeout=30.0, duration=0.4)
        assert spin_until(ros, lambda: served, 10.0, ros.executor_for_tests)
    finally:
        ros.destroy_subscription(sub)
    assert res.error_code == AverageProximity.Response.SUCCESS, res.message
    assert res.distance == pytest.approx(true_gap(truth, moved.positions, 'P5'), abs=1e-4)
    mark = marks.read_average_mark(served[-1])
    after_t0 = [ns_to_s(stamp - mark.t0_ns) for stamp in mark.stamps_ns]
    assert len(after_t0) == res.sample_count + res.rejected_count >= 2
    # readings over 0.4 s of ROS time: a wait of 0.4 s of wall time would go on to 0.8 s of it
    # at 2x, and end at 0.2 s at 0.5x (a starved sensor only ends it early)
    assert min(after_t0) >= 0.0 and max(after_t0) <= 0.4 + 1e-6
    if rate < 1.0:
        assert max(after_t0) > 0.28
