"""mock_robot stopped (Ctrl-C) in the middle of a long move: the move ends at once, its goal is
aborted for the client with the reason, and the process exits 0 without a traceback.

A move that outlasted spin.STOP_GRACE used to call goal_handle.succeed() after its action
server was destroyed ("feedback publisher is invalid": a traceback in the log, seen in
test_up's Ctrl-C test on a loaded machine). Its own ROS domain, not the session's suite.
"""
import os
import signal
import subprocess
import time

import domain_coordinator
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from cobot_calib_msgs.action import MoveTo
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import spin_until

TIMEOUT = 60.0      # [s] for the node to start (cold imports on a loaded machine)


@pytest.fixture
def mock_robot(tmp_path):
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        # time_scale 1: motion in real time, so a slow move lasts far beyond STOP_GRACE
        cmd = launcher.NodeSpec('mock_robot', {'time_scale': '1.0'}).command()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, env=env)
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('mock_robot_stop_test', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            yield proc, node, executor
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
            node.destroy_node()
            rclpy.try_shutdown(context=context)


def test_ctrl_c_in_a_long_move_aborts_its_goal_and_exits_cleanly(mock_robot):
    proc, node, executor = mock_robot
    seen = []
    node.create_subscription(JointState, 'joint_states', seen.append, qos_profile_sensor_data)
    client = ActionClient(node, MoveTo, 'move_to')
    assert spin_until(node, lambda: seen and client.server_is_ready(), TIMEOUT, executor)
    target = list(seen[-1].position)
    target[0] += 0.5
    feedback = []
    # 0.5 rad at 5 % of 1 rad/s: 10 s of motion
    sent = client.send_goal_async(
        MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS, positions=target, speed_scale=0.05),
        feedback_callback=feedback.append)
    assert spin_until(node, lambda: sent.done(), 10.0, executor)
    goal = sent.result()
    assert goal.accepted
    result = goal.get_result_async()          # asked for at once, as every client does
    # a second of motion: the server's side of the result service has discovered this client
    # by then (right after start-up its answer can be lost: "the client may have gone away")
    # 1 s into the move: 10 feedback messages at mock_robot's 10 Hz (FEEDBACK_EVERY_STEPS)
    assert spin_until(node, lambda: len(feedback) >= 10, 10.0, executor)

    proc.send_signal(signal.SIGINT)
    stopped = time.monotonic()
    if not spin_until(node, lambda: result.done(), spin.STOP_GRACE, executor):
        proc.kill()
        pytest.fail(f'no result before the node was torn down:\n{proc.communicate()[0]}')
    answer = result.result().result
    assert answer.error_code == MoveTo.Result.CANCELED       # stopped, not unreachable
    assert 'shutting down' in answer.message
    assert abs(answer.positions[0] - target[0]) > 0.1          # it stopped on the way
    out, _ = proc.communicate(timeout=2 * spin.STOP_GRACE + 10.0)
    assert time.monotonic() - stopped < 10.0 - 2.0, out        # not the move's remaining time
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
