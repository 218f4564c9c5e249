"""ros.calls.run_action against a server process that is killed and started again (issue 31
item 2): the new instance does not know the goal, so the wait ends naming the node and saying
the goal was lost, instead of waiting for a result that never comes. Real processes, real
signals, on a ROS domain of their own."""
import os
import threading
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
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import CallError, run_action, spin_until
from machine import short_lease

START_TIMEOUT = 60.0     # [s] for a node to start (cold imports on a loaded machine)
GOAL_TIMEOUT = 150.0     # [s] run_action's own bound: beyond the move (50 s) and the lease


@pytest.fixture
def server(tmp_path):
    """mock_robot in real time (a slow move lasts long), restartable, and a client node."""
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        env = short_lease(env)      # the killed instance leaves the graph after 6 s, not 20
        cmd = launcher.NodeSpec('mock_robot', {'time_scale': '1.0'}).command()
        procs = []

        def start() -> subprocess.Popen:
            procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL, env=env))
            return procs[-1]

        context = Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('run_action_test', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        try:
            yield start, node, executor
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            node.destroy_node()
            rclpy.try_shutdown(context=context)


def test_a_goal_lost_to_a_restarted_server_ends_the_wait_naming_the_node(server):
    start, node, executor = server
    first = start()
    seen = []
    node.create_subscription(JointState, 'joint_states', seen.append, qos_profile_sensor_data)
    client = ActionClient(node, MoveTo, 'move_to')
    assert spin_until(node, lambda: seen and client.server_is_ready(), START_TIMEOUT, executor)
    target = list(seen[-1].position)
    target[0] += 1.0
    # 1 rad at 2 % of 1 rad/s: 50 s of motion, killed at its first feedback
    goal = MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS, positions=target,
                       speed_scale=0.02)
    killed = []

    def kill_and_restart(_feedback) -> None:
        if not killed:
            first.kill()                   # SIGKILL: its participant stays until the lease
            first.wait()
            killed.append(time.monotonic())
            start()                        # as `cobot-calib up` restarts a node that exited

    with pytest.raises(CallError) as error:
        run_action(node, client, goal, GOAL_TIMEOUT, feedback=kill_and_restart,
                   executor=executor)
    assert killed, 'no feedback before the wait ended'
    message = str(error.value)
    assert message.startswith('the mock_robot node restarted: goal lost'), message
    assert 'move_to goal' in message, message
    # the goal's own deadline was not what ended it: the lease (6 s) and GONE_AFTER (3 s)
    waited = time.monotonic() - killed[0]
    assert waited < GOAL_TIMEOUT - 50.0, waited


def test_a_move_a_node_waits_on_ends_when_the_robot_restarts(server):
    """issue 38 item 1, inside a node: RobotCalls' move_to (on a spin.Companion, as every job
    node moves the arm) whose mock_robot is killed and started again fails naming it, instead
    of waiting out MOVE_TIMEOUT (120 s) for a result that never comes."""
    from action_msgs.msg import GoalStatus, GoalStatusArray
    import numpy as np
    from cobot_calib_ros.core.robot_port import MoveFailed
    from cobot_calib_ros.ros.robot_calls import RobotCalls
    from cobot_calib_ros.ros.spin import Companion
    start, node, executor = server
    first = start()
    seen, executing = [], []
    node.create_subscription(JointState, 'joint_states', seen.append, qos_profile_sensor_data)
    def on_status(msg: GoalStatusArray) -> None:
        executing.extend(s for s in msg.status_list if s.status == GoalStatus.STATUS_EXECUTING)
    node.create_subscription(GoalStatusArray, 'move_to/_action/status', on_status, 10)
    answers = Companion(node, 'answers')
    calls = RobotCalls(answers)
    try:
        assert spin_until(node, lambda: bool(seen), START_TIMEOUT, executor)
        target = np.array(seen[-1].position)
        target[0] += 1.0                    # 50 s of motion at 2 % of 1 rad/s
        failed = []

        def move() -> None:
            try:
                calls.move_joints(target, speed_scale=0.02)
            except MoveFailed as e:
                failed.append(str(e))
        mover = threading.Thread(target=move, daemon=True)
        mover.start()
        assert spin_until(node, lambda: bool(executing), START_TIMEOUT, executor)
        first.kill()
        first.wait()
        start()                             # as `cobot-calib up` restarts a node that exited
        mover.join(timeout=GOAL_TIMEOUT)
        assert failed, 'the move neither failed nor ended'
        assert failed[0].startswith('move_to: the mock_robot node restarted: goal lost'), failed
    finally:
        answers.destroy()


def test_the_move_client_is_there_while_moves_need_it_and_made_again_after(server,
                                                                           monkeypatch):
    """RobotCalls' move_to client: none at rest (an action client takes every status and
    feedback message of every goal, another node's collection too), made by a move, released
    MOVE_CLIENT_LINGER after the last one, and made again by the next move, which works."""
    import numpy as np
    from cobot_calib_ros.ros import robot_calls
    from cobot_calib_ros.ros.spin import Companion
    monkeypatch.setattr(robot_calls, 'MOVE_CLIENT_LINGER', 1.0)
    start, node, executor = server
    start()
    seen = []
    node.create_subscription(JointState, 'joint_states', seen.append, qos_profile_sensor_data)
    answers = Companion(node, 'answers')
    calls = robot_calls.RobotCalls(answers)

    def status_readers() -> list[str]:
        return [i.node_name for i in node.get_subscriptions_info_by_topic(
            '/move_to/_action/status')]
    try:
        assert spin_until(node, lambda: bool(seen), START_TIMEOUT, executor)
        assert status_readers() == []
        home = np.array(seen[-1].position)
        for step in (0.01, 0.02):
            reached = calls.move_joints(home + step)
            np.testing.assert_allclose(reached, home + step, atol=1e-6)
            assert status_readers() == ['_run_action_test_answers']
            assert spin_until(node, lambda: status_readers() == [], 10.0, executor), \
                'the move_to client was not released'
    finally:
        answers.destroy()
