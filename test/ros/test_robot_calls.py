"""ros.robot_calls: a hold that finds too few joint_states (NO_DATA) is tried again, and every
retry is counted (RobotCalls.capture_retries) and shown on /diagnostics (Diagnostics.watch), so
a stalling stream shows instead of only costing time."""
import threading

from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState

from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.nodes.joint_state_monitor import JointStateMonitor
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, status_name
from cobot_calib_ros.ros.robot_calls import CAPTURE_ATTEMPTS, RobotCallError, RobotCalls

NS = 'starved_calls'
SLOW_RATE = 20.0     # [Hz] of joint_states: a starved 1 kHz stream


@pytest.fixture
def starved():
    """A joint_state_monitor (expects 1 kHz) fed at SLOW_RATE, and a caller node beside it,
    spun on a thread of this process."""
    context = Context()
    rclpy.init(context=context)
    monitor = JointStateMonitor(context=context, namespace=NS)
    caller = rclpy.create_node('caller', namespace=NS, context=context)
    joints = caller.create_publisher(JointState, 'joint_states', 10)

    def publish() -> None:
        msg = JointState(name=['j0', 'j1'], position=[0.1, 0.2])
        msg.header.stamp = caller.get_clock().now().to_msg()
        joints.publish(msg)
    caller.create_timer(1.0 / SLOW_RATE, publish)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(monitor)
    executor.add_node(caller)
    running = True

    def run() -> None:
        while running:
            executor.spin_once(timeout_sec=0.05)
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    answers = spin.Companion(caller, 'answers')
    try:
        yield caller, answers
    finally:
        running = False
        thread.join(timeout=5)
        answers.destroy()
        executor.shutdown(timeout_sec=1)
        monitor.destroy_node()
        caller.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_starved_capture_is_retried_counted_and_shown(starved):
    caller, answers = starved
    calls = RobotCalls(answers)
    health = Diagnostics(caller, period=0.2)
    health.watch(capture_retries=lambda: calls.capture_retries)
    seen = []
    listener = answers.node.create_subscription(
        DiagnosticArray, '/diagnostics', lambda msg: seen.extend(
            {v.key: v.value for v in s.values} for s in msg.status
            if s.name == status_name(caller)), 10)
    assert calls.capture_retries == 0
    with pytest.raises(RobotCallError, match=r'capture_joints: only \d joint_states samples in '
                                             r'0\.100 s \(need 50\)'):
        calls.capture(0.1)
    assert calls.capture_retries == CAPTURE_ATTEMPTS - 1         # every try but the first
    assert spin_until(caller, lambda: seen and seen[-1]['capture_retries'] == '3', 10.0,
                      _Idle()), seen[-1:]
    answers.node.destroy_subscription(listener)


class _Idle:
    """An 'executor' for spin_until that only waits: the nodes spin on their own threads."""

    def spin_once(self, timeout_sec: float) -> None:
        threading.Event().wait(timeout_sec)
