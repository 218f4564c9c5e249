"""ros.robot_calls.RobotCalls, in-process on the session's domain (namespaces where no suite
runs): a hold that finds too few joint_states (NO_DATA) is tried again, and every retry is
counted (RobotCalls.capture_retries) and shown on /diagnostics (Diagnostics.watch), so a
stalling stream shows instead of only costing time; a touch on a real cell (a driver serves
move_to but no mock_robot/hand_guide answers) waits for the operator's confirm_touch call."""
import threading

from cobot_calib_msgs.action import MoveTo
from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.action import ActionServer
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from cobot_calib_ros.core.robot_port import MoveFailed
from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.nodes.joint_state_monitor import JointStateMonitor
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, status_name
from cobot_calib_ros.ros.robot_calls import CAPTURE_ATTEMPTS, NO_MOVE_TO, RobotCallError, RobotCalls
from cobot_calib_ros.ros.spin import Companion, wait

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

    stop = threading.Event()

    def publish() -> None:
        """On its own thread, not a timer of the executor that the monitor's capture blocks:
        the stream goes on thinly during a hold (starved), it does not stop (a stopped stream
        is refused only after the monitor's STALL_TIMEOUT, each of the 4 tries)."""
        while not stop.wait(1.0 / SLOW_RATE):
            msg = JointState(name=['j0', 'j1'], position=[0.1, 0.2])
            msg.header.stamp = caller.get_clock().now().to_msg()
            joints.publish(msg)
    publisher = threading.Thread(target=publish, daemon=True)
    publisher.start()
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
        stop.set()
        thread.join(timeout=5)
        publisher.join(timeout=5)
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
    # (the hold goes on for up to 0.4 s more while samples still come: HOLD_EXTENSIONS)
    with pytest.raises(RobotCallError, match=r'capture_joints: only \d+ joint_states samples in '
                                             r'(0\.100 s|0\.[2-5]00 s \(the 0\.100 s hold went '
                                             r'on\)) \(need 50\)'):
        calls.capture(0.1)
    assert calls.capture_retries == CAPTURE_ATTEMPTS - 1         # every try but the first
    assert spin_until(caller, lambda: seen and seen[-1]['capture_retries'] == '3', 10.0,
                      _Idle()), seen[-1:]
    answers.node.destroy_subscription(listener)


class _Idle:
    """An 'executor' for spin_until that only waits: the nodes spin on their own threads."""

    def spin_once(self, timeout_sec: float) -> None:
        threading.Event().wait(timeout_sec)


TIMEOUT = 30.0      # [s]: the touch first looks for the mock's hand_guide for SERVER_WAIT


@pytest.fixture
def real_cell():
    """(context, the driver node: move_to only, spinning on its own thread)."""
    context = Context()
    rclpy.init(context=context)
    driver = rclpy.create_node('driver', namespace='/real_cell', context=context)
    ActionServer(driver, MoveTo, 'move_to', execute_callback=lambda handle: MoveTo.Result())
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(driver)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    yield context, driver
    executor.shutdown()
    rclpy.try_shutdown(context=context)


def _calls(context, name, namespace='/real_cell', **options):
    node = rclpy.create_node(name, namespace=namespace, context=context)
    answers = Companion(node, 'clients')
    return answers, RobotCalls(answers, **options)


def _touch_in_thread(calls, name, outcome):
    try:
        calls.touch(name)
        outcome.append('touched')
    except MoveFailed as e:
        outcome.append(str(e))


def test_a_touch_without_the_mock_waits_for_the_operator_to_confirm(real_cell):
    context, driver = real_cell
    answers, calls = _calls(context, 'solver', operator='solver')
    try:
        assert calls.confirm_service == 'solver/confirm_touch'
        outcome = []
        toucher = threading.Thread(target=_touch_in_thread, args=(calls, 'P2', outcome))
        toucher.start()
        assert calls.awaiting_operator.wait(TIMEOUT), outcome
        assert outcome == []                          # still waiting for the operator
        confirm = driver.create_client(Trigger, '/real_cell/solver/confirm_touch')
        assert confirm.wait_for_service(timeout_sec=TIMEOUT)
        answer = wait(confirm.call_async(Trigger.Request()), TIMEOUT)
        assert answer.success and answer.message == 'touch confirmed'
        toucher.join(TIMEOUT)
        assert outcome == ['touched'] and not calls.awaiting_operator.is_set()
        assert calls.robot_seconds == 0.0             # the operator's time is not robot time
    finally:
        answers.destroy()


def test_a_touch_with_neither_operator_nor_mock_says_so(real_cell):
    answers, calls = _calls(real_cell[0], 'nobody')
    try:
        outcome = []
        _touch_in_thread(calls, 'P1', outcome)
        assert outcome == ['touch P1: no operator to confirm it (the node serves no '
                           'confirm_touch) and no simulated one (mock_robot/hand_guide)']
    finally:
        answers.destroy()


def test_a_touch_without_a_robot_names_the_driver_to_start():
    context = Context()
    rclpy.init(context=context)
    try:
        answers, calls = _calls(context, 'alone', '/no_robot', operator='alone')
        outcome = []
        _touch_in_thread(calls, 'P1', outcome)
        answers.destroy()
        assert outcome == [NO_MOVE_TO]
    finally:
        rclpy.try_shutdown(context=context)
