"""spin: the executor choice; timers and Companion threads running, and clean exits, in node
processes of each executor (a hung executor is killed with its process, never hangs the test);
a Wake ends an executor's long idle wait at once.

They run on a ROS domain of their own (domain_coordinator), not the session's.
"""
import os
from pathlib import Path
import select
import signal
import subprocess
import sys
import threading
import time

from cobot_calib_msgs.action import MoveTo
import domain_coordinator
import pytest
import rclpy
from rclpy.action import ActionServer
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node

from cobot_calib_ros.api.launcher import STOP_WAIT
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import spin_until

TIMEOUT = 30.0          # [s] for a node process to start (cold imports on a loaded machine)
NODE_SCRIPT = '''
import sys
from rclpy.node import Node
from std_msgs.msg import String
from cobot_calib_ros.api.launcher import STOP_WAIT
from cobot_calib_ros.ros import spin

# idle waits longer than the test's TIMEOUT: a stop must not wait for one to end
spin.IDLE_WAKE = 600.0


class Ticker(Node):
    """A timer that publishes, and a Companion's subscription that receives it."""

    def __init__(self):
        super().__init__('spin_test_ticker')
        self.receiver = spin.Companion(self, 'receiver')
        self.got = 0
        self.receiver.node.create_subscription(String, 'spin_test', self._on_message, 10)
        self.pub = self.create_publisher(String, 'spin_test', 10)
        self.create_timer(0.05, lambda: self.pub.publish(String(data='tick')))

    def _on_message(self, _):
        self.got += 1
        if self.got == 3:
            print('ticking and receiving', flush=True)

    def destroy_node(self):
        self.receiver.destroy()
        return super().destroy_node()


spin.run(Ticker, sys.argv)
'''


@pytest.fixture(scope='module')
def domain():
    with domain_coordinator.domain_id() as domain_id:
        yield domain_id


def test_the_executor_comes_from_the_environment(monkeypatch):
    monkeypatch.delenv(spin.EXECUTOR_ENV, raising=False)
    assert spin.executor_kind() == spin.DEFAULT_EXECUTOR
    monkeypatch.setenv(spin.EXECUTOR_ENV, ' Events ')
    assert spin.executor_kind() == 'events'
    monkeypatch.setenv(spin.EXECUTOR_ENV, 'multi')
    with pytest.raises(ValueError, match='single'):
        spin.executor_kind()


LONG_WAIT = 60.0        # [s] an idle wait that only a wake ends within the test's joins


@pytest.fixture
def context():
    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.mark.parametrize('make', [SingleThreadedExecutor,
                                  lambda context: MultiThreadedExecutor(2, context=context)],
                         ids=['single', 'multi'])
def test_a_wake_ends_a_long_spin_once(context, make):
    """rclpy's Executor.wake does not: it only has the wait set rebuilt, and the wait goes on
    until the timeout (spin_once(3.0) woken after 0.5 s returned after 3.0 s), so with a long
    idle wait a stop went unseen that long (issue 38.4)."""
    node = Node('wake_test', context=context)
    executor = make(context=context)
    executor.add_node(node)
    wake = spin.Wake(node)
    spinning = threading.Thread(target=executor.spin_once, args=(LONG_WAIT,), daemon=True)
    try:
        spinning.start()
        spinning.join(0.5)          # into its wait, or not yet: the wake ends it either way
        wake()
        spinning.join(10.0)
        assert not spinning.is_alive()
    finally:
        spinning.join(LONG_WAIT)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()


def test_a_destroyed_companion_stops_at_once_with_a_long_idle_wait(context, monkeypatch):
    """Companion.destroy joins its thread for 2 s, then gives up and leaves the teardown to
    run beside a companion still in its wait: it did so whenever that wait outlasted the join
    (Executor.wake did not end it)."""
    monkeypatch.setattr(spin, 'IDLE_WAKE', LONG_WAIT)
    owner = Node('companion_owner', context=context)
    companion = spin.Companion(owner, 'helper')
    try:
        spin.wait(companion.submit(lambda: None), 10.0)     # spinning; idle from here on
        companion.destroy()
        assert not companion._thread.is_alive()
    finally:
        owner.destroy_node()


def test_a_goal_the_server_no_longer_knows_ends_as_lost_not_with_a_default_result(
        context, monkeypatch):
    """Companion.run_action: a server asked for the result of a goal it no longer keeps (past
    its result_timeout; mock_robot keeps a move's MOVE_RESULT_KEEP s) answers STATUS_UNKNOWN
    with a default result, whose error code 0 reads as success: ServerLost instead. The
    result is asked for here 2 s after the goal ended, against a 1 s result_timeout."""
    server = Node('result_keeper', context=context)
    ActionServer(server, MoveTo, 'result_keep_test', result_timeout=1,
                 execute_callback=lambda handle: (handle.succeed(), MoveTo.Result())[1])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(server)
    spinning = threading.Thread(target=executor.spin, daemon=True)
    spinning.start()
    owner = Node('result_asker', context=context)
    companion = spin.Companion(owner, 'asker')
    client = ActionClient(companion.node, MoveTo, 'result_keep_test')

    def asked_late(client, goal, accept_timeout):
        handle = spin.wait(spin.wait(companion.submit(client.send_goal_async, goal),
                                     accept_timeout), accept_timeout)
        time.sleep(3.0)
        return handle, spin.wait(companion.submit(handle.get_result_async), accept_timeout)
    monkeypatch.setattr(companion, 'send_goal', asked_late)
    try:
        assert spin.until(client.server_is_ready, 10.0)
        with pytest.raises(spin.ServerLost, match='does not know the goal'):
            companion.run_action(client, MoveTo.Goal(), 10.0, 10.0)
    finally:
        companion.destroy()
        owner.destroy_node()
        executor.shutdown(timeout_sec=1.0)
        server.destroy_node()


def _printed(proc: subprocess.Popen, line: str, timeout: float) -> bool:
    """Whether the process prints ``line`` within ``timeout`` [s]. Other lines are passed
    over: Fast DDS logs a shared-memory port another process on the machine holds."""
    deadline = time.monotonic() + timeout
    while (remaining := deadline - time.monotonic()) > 0:
        if not select.select([proc.stdout], [], [], remaining)[0]:
            return False
        printed = proc.stdout.readline()
        if printed.strip() == line:
            return True
        if not printed:             # it exited
            return False
    return False


def _start_node(kind: str, domain: int) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1', **{spin.EXECUTOR_ENV: kind})
    return subprocess.Popen([sys.executable, '-c', NODE_SCRIPT], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            cwd=Path(__file__).resolve().parents[2])


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('kind', spin.EXECUTORS)
def test_a_node_runs_and_exits_cleanly_on_a_signal(domain, kind, signum):
    """Timers and Companion subscriptions run (EventsExecutor.spin() of rclpy 7.1.6 ran no
    timer here), and the node exits 0 on SIGINT and SIGTERM (with the EventsExecutor, Ctrl-C
    once ended in exit code 130: a late KeyboardInterrupt in destroy_node)."""
    proc = _start_node(kind, domain)
    try:
        assert _printed(proc, 'ticking and receiving', TIMEOUT)
        proc.send_signal(signum)
        out, _ = proc.communicate(timeout=TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out


@pytest.mark.parametrize('value, reason', [
    ('100.0', 'out of range Min: 0.01, Max: 10.0, value: 100.0'),
    ('fast', "of type 'STRING', expecting type 'DOUBLE'")])
def test_a_bad_parameter_value_at_start_ends_the_node_with_one_line(domain, value, reason):
    """-p joint_velocity:=100.0 (beyond its declared range) or a word where a number goes: the
    node exits 1 naming the parameter, with no traceback."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    out = subprocess.run([sys.executable, '-m', 'cobot_calib_ros.nodes.mock_robot', '--ros-args',
                          '-p', f'joint_velocity:={value}'], capture_output=True, text=True,
                         env=env, timeout=TIMEOUT, cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert 'Traceback' not in out.stderr and len(lines) == 1, out.stderr
    assert reason in lines[0] and 'joint_velocity' in lines[0]
    assert lines[0].endswith("fix the -p value or config/<node>.yaml (the README's "
                             "Configuration section gives each parameter's unit)")


NATIVE_EXIT = '''
import ctypes, sys, time
from cobot_calib_ros.api.launcher import STOP_WAIT
from cobot_calib_ros.ros import spin
timer = spin.NativeExitTimer(0.3)
if sys.argv[1] == 'cancel':
    timer.cancel()
    time.sleep(0.6)
    sys.exit(3)
ctypes.PyDLL(None).sleep(60)      # a C call that keeps the GIL: no Python thread runs
'''


def test_the_native_exit_timer_ends_a_process_stuck_in_c_with_the_gil_held_with_exit_0():
    start = time.monotonic()
    out = subprocess.run([sys.executable, '-c', NATIVE_EXIT, 'hang'], timeout=60)
    assert out.returncode == 0 and time.monotonic() - start < 30


def test_a_cancelled_native_exit_timer_leaves_the_process_alone():
    out = subprocess.run([sys.executable, '-c', NATIVE_EXIT, 'cancel'], timeout=60)
    assert out.returncode == 3


HUNG_TEARDOWN = '''
import ctypes, sys
from rclpy.node import Node
from cobot_calib_ros.api.launcher import STOP_WAIT
from cobot_calib_ros.ros import spin


class Hangs(Node):
    """Its destroy blocks in C with the GIL held, as rclpy's did in Fast DDS's node delete."""

    def __init__(self):
        super().__init__('spin_test_hangs')
        print('up', flush=True)

    def destroy_node(self):
        print('tearing down', flush=True)
        ctypes.PyDLL(None).sleep(60)


spin.run(Hangs, sys.argv)
'''


def _hung_teardown(domain) -> subprocess.Popen:
    """A node process stopped by SIGINT, now in a teardown hung in C (HUNG_TEARDOWN)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    proc = subprocess.Popen([sys.executable, '-c', HUNG_TEARDOWN], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            cwd=Path(__file__).resolve().parents[2])
    assert _printed(proc, 'up', TIMEOUT)
    proc.send_signal(signal.SIGINT)
    assert _printed(proc, 'tearing down', TIMEOUT)
    return proc


def test_a_teardown_hung_in_c_ends_with_exit_0_before_the_launchers_sigterm(domain):
    """A teardown hung in rclpy's C++ destroy (GIL held, no Python handler can run) is ended
    by the node's own watchdog (exit 0) within spin.STOP_BOUND of the stop, before the
    launcher's SIGTERM (STOP_WAIT after its SIGINT; it was 6 s, before the watchdog's 11 s,
    and such a node ended -15 in a test of `up`'s Ctrl-C)."""
    proc = _hung_teardown(domain)
    try:
        proc.wait(timeout=STOP_WAIT)
    finally:
        if proc.poll() is None:
            proc.kill()
        out, _ = proc.communicate()
    assert proc.returncode == 0, out


GOAL_AT_STOP = '''
import sys, time
from rclpy.action import ActionServer
from rclpy.node import Node
from cobot_calib_msgs.action import MoveTo
from cobot_calib_ros.ros import spin


class Working(Node):
    """A goal that runs until the node is stopped, then ends aborted."""

    def __init__(self):
        super().__init__('spin_test_working')
        ActionServer(self, MoveTo, 'spin_test_work', self._work)
        print('up', flush=True)

    def _work(self, goal_handle):
        print('working', flush=True)
        while not spin.stopping():
            time.sleep(0.01)
        goal_handle.abort()
        return MoveTo.Result(error_code=MoveTo.Result.CANCELED, message='stopped')


spin.run(Working, sys.argv, threads=2)
'''


def test_a_node_stopped_with_a_goal_running_answers_on_for_result_linger(domain):
    """The goal ends aborted for its client, and the node goes on spinning RESULT_LINGER s
    after its work ended: torn down ~0.1 s after sending the result, a loaded client handled
    the result writer's end (DDS discovery) before its data and lost the result (a Ctrl-C'd
    `up` during a collection: the client said "node is gone"). A lower bound on the exit."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    proc = subprocess.Popen([sys.executable, '-c', GOAL_AT_STOP], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env,
                            cwd=Path(__file__).resolve().parents[2])
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = Node('spin_test_work_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = ActionClient(node, MoveTo, 'spin_test_work')
    try:
        assert _printed(proc, 'up', TIMEOUT)
        assert spin_until(node, client.server_is_ready, TIMEOUT, executor)
        send = client.send_goal_async(MoveTo.Goal())
        assert spin_until(node, send.done, TIMEOUT, executor) and send.result().accepted
        result = send.result().get_result_async()
        assert _printed(proc, 'working', TIMEOUT)
        proc.send_signal(signal.SIGINT)
        stopped = time.monotonic()
        assert spin_until(node, result.done, TIMEOUT, executor)
        proc.wait(timeout=STOP_WAIT)
        exited = time.monotonic()
    finally:
        client.destroy()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        if proc.poll() is None:
            proc.kill()
        out, _ = proc.communicate()
    assert result.result().result.message == 'stopped' and proc.returncode == 0, out
    assert exited - stopped >= spin.RESULT_LINGER, out


def test_a_node_with_only_a_timer_in_flight_at_a_stop_does_not_linger(domain, monkeypatch):
    """RESULT_LINGER is for a goal's result: a stop that finds a timer callback running (as
    mock_robot's publishing often is) waits for it, then goes on at once (every `up` stop
    took 1.7 s instead of 0.2 s when any callback in flight counted)."""
    monkeypatch.setattr(spin, 'RESULT_LINGER', 60.0)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = Node('spin_test_timer_at_stop', context=context)
    executor = MultiThreadedExecutor(2, context=context)
    executor.add_node(node)
    running = threading.Event()

    def slow_tick() -> None:
        timer.cancel()                  # once
        running.set()
        time.sleep(0.3)
    timer = node.create_timer(0.01, slow_tick)
    try:
        deadline = time.monotonic() + TIMEOUT
        while not running.is_set() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert running.is_set()
        started = time.monotonic()
        spin._finish_work_in_flight(executor, context)
        took = time.monotonic() - started
    finally:
        spin._stopping.clear()          # this process goes on
        executor.shutdown(timeout_sec=5.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert took < 30.0


def test_a_sigterm_ends_a_teardown_hung_in_c_at_once(domain):
    """From its teardown on a node takes SIGTERM's default action: a launcher's SIGTERM ends a
    hung teardown at once (-15), not after the watchdog."""
    proc = _hung_teardown(domain)
    try:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=spin.TEARDOWN_EXIT / 2)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
    assert proc.returncode == -signal.SIGTERM


class _Future:
    """A future that another thread may complete (as a client's executor does)."""

    def __init__(self) -> None:
        self._callbacks, self.value = [], None

    def done(self) -> bool:
        return self.value is not None

    def result(self):
        return self.value

    def add_done_callback(self, callback) -> None:
        self._callbacks.append(callback)

    def set_result(self, value) -> None:
        self.value = value
        for callback in self._callbacks:
            callback(self)


def _sender(answered: set):
    """send() for wait_answer: the requests whose index is in ``answered`` get their answer
    from another thread 0.05 s later; (send, the futures sent)."""
    futures = []

    def send():
        future = _Future()
        if len(futures) in answered:
            threading.Timer(0.05, future.set_result, args=(f'answer {len(futures)}',)).start()
        futures.append(future)
        return future
    return send, futures


def test_a_query_whose_answer_was_dropped_is_sent_again():
    send, futures = _sender({1})
    forgotten = []
    assert spin.wait_answer(send, 30.0, 1.0, forgotten.append) == 'answer 1'
    assert len(futures) == 2 and forgotten == [futures[0]]


def test_a_query_never_answered_ends_at_its_timeout_every_request_forgotten():
    send, futures = _sender(set())
    forgotten = []
    with pytest.raises(TimeoutError):
        spin.wait_answer(send, 0.5, 0.2, forgotten.append)
    assert len(futures) >= 2 and forgotten == futures
