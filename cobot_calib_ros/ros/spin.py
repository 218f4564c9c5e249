"""The one way a node process runs: init, spin, clean shutdown on Ctrl-C or SIGTERM.

Which executor spins a node and its companions is one choice per process, read from the
environment variable ``COBOT_CALIB_EXECUTOR``: ``single`` (rclpy's SingleThreadedExecutor) or
``events`` (rclpy.experimental.EventsExecutor, C++). Unset or empty means DEFAULT_EXECUTOR;
bench/ measures both side by side. A node with ``threads`` > 1 spins a MultiThreadedExecutor;
its companions still follow the choice.

The EventsExecutor takes half the CPU for 1 kHz joint_states (joint_state_monitor 12-14 % of
a core against 23-30 %) and lost none where the SingleThreadedExecutor once lost 175 of 58 k on
a loaded machine, but rclpy 7.1.6's build misbehaves: spin() and spin_once() without a timeout
hang (no timer or subscription callback runs, SIGINT does not stop it), it installs its own
SIGINT/SIGTERM handling (rclpy's signal options do not apply), and a Ctrl-C once ended in exit
code 130. run (spin_once with a timeout, in a loop) and _teardown work around all three, but
being experimental upstream and misbehaving here, it is not the default.

On Ctrl-C or SIGTERM a node's work in flight ends first: every ``wait`` for an answer raises
``Stopping`` (a TimeoutError), so a goal that waits on the robot fails the way a lost robot
makes it fail (a trial or collection is marked aborted, resumable, its data on disk, and the
goal ends aborted for its client), while the executor still spins, for up to STOP_GRACE s;
then the node is destroyed and the process exits 0 at once (_exit_now says why). rclpy's own signal handlers are not installed for this: they shut
the context down first, and every goal still running then failed with a traceback.
"""
from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import os
import signal
import sys
import threading
import time
from typing import Callable

from action_msgs.msg import GoalStatus
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import (InvalidHandle, InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.executors import (Executor, ExternalShutdownException, MultiThreadedExecutor,
                             SingleThreadedExecutor)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from cobot_calib_ros.ros.time import s_to_ns, split_ns

EXECUTOR_ENV = 'COBOT_CALIB_EXECUTOR'
EXECUTORS = ('events', 'single')
DEFAULT_EXECUTOR = 'single'
WAKE_PERIOD = 0.1     # [s] longest wait of one spin_once of a loop that checks for a stop
# [s] longest wait of an idle executor's spin_once (a node's own, a companion's): a stop ends
# it at once (Wake: a signal through SignalWaker, a companion's destroy), so this only bounds a
# missed wake; at WAKE_PERIOD an idle node's 10 Hz wait-set rebuilds were most of its CPU, and
# at 2 s a job node's three or four executors still woke ~2 times a second between them (an
# idle wake of rclpy's executor: 1 ms of CPU in a loop here, up to ~10 ms when it comes cold)
IDLE_WAKE = 10.0
STOP_GRACE = 3.0      # [s] for callbacks in flight to end after a stop, before the teardown
# [s] a node that had a goal running at a stop goes on spinning this long before its
# teardown, so its last answers are taken before its writers go. Destroying a writer is
# announced to peers on DDS's discovery traffic, which a loaded client can handle before the
# data that writer sent just before (another port, another thread of Fast DDS): that data is
# then dropped as coming from an unknown writer. A Ctrl-C'd `up` during a collection lost the
# goal's result so (the client said "node is gone"), once also its status: 5 of 29 runs at
# load ~6, the node torn down 0.1-0.2 s after sending (none of 32 with this); a result asked
# for again meanwhile is answered too (ros.calls.ResultWait).
RESULT_LINGER = 1.5
TEARDOWN_DUMP = 4.0   # [s] a teardown still running this long prints every thread's stack
# [s] a teardown still running this long ends the process (exit 0, said in its log): rclpy's
# Node.destroy_node hung in it (seen once more at load ~4, a camera suite's
# joint_state_monitor: SIGKILLed 32 s after its SIGINT), after the node's work had ended.
# Short enough that STOP_BOUND ends before a launcher's SIGTERM (a healthy teardown takes
# well under a second; one cut short leaves only Fast DDS files, removed at the next start)
TEARDOWN_EXIT = 5.0
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
LAUNCHER_PID_ENV = 'COBOT_CALIB_LAUNCHER_PID'   # set by api.launcher for the nodes it starts
PR_SET_PDEATHSIG = 1
_stopping = threading.Event()     # set once this process is shutting down


class Stopping(TimeoutError):
    """A wait ended because the process is shutting down (Ctrl-C, SIGTERM)."""


def executor_kind() -> str:
    """``events`` or ``single``, from $COBOT_CALIB_EXECUTOR (unset: DEFAULT_EXECUTOR)."""
    kind = os.environ.get(EXECUTOR_ENV, '').strip().lower() or DEFAULT_EXECUTOR
    if kind not in EXECUTORS:
        raise ValueError(f'{EXECUTOR_ENV}={kind!r}: use one of {", ".join(EXECUTORS)}')
    return kind


def make_executor(context=None, kind: str | None = None) -> Executor:
    """A single-threaded executor of the chosen kind (``kind`` or executor_kind())."""
    kind = kind or executor_kind()
    if kind == 'events':
        from rclpy.experimental import EventsExecutor  # experimental upstream: imported lazily
        return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def run(make_node: Callable[[], Node], args=None, threads: int = 1) -> None:
    """Spin the node built by `make_node`; `threads` > 1 uses a MultiThreadedExecutor, else
    the executor of executor_kind(). Ctrl-C and SIGTERM stop it in two steps: the work in
    flight ends first (see _finish_work_in_flight), with the executor still spinning, then the
    node is destroyed."""
    die_with_launcher()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, _stop_handler(stop)) for sig in STOP_SIGNALS}
    node = executor = waker = None
    try:
        node = make_node()
        executor = (MultiThreadedExecutor(num_threads=threads) if threads > 1
                    else make_executor())
        executor.add_node(node)
        waker = SignalWaker(wake_for(node, executor))
        period = idle_wake(executor)
        while node.context.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=period)
        _finish_work_in_flight(executor, node.context)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        # a -p / --params-file value of the wrong type or out of the declared range: one line
        raise SystemExit(f'{exc}; fix the -p value or config/<node>.yaml (the README\'s '
                         'Configuration section gives each parameter\'s unit)')
    except _rclpy.RCLError:
        # the context shut down under the executor (the EventsExecutor's own signal handling,
        # or rclpy.shutdown from a node): an executor building its next wait set then fails
        # with "context is not valid": that is the shutdown asked for
        if node is None or node.context.ok():
            raise
    finally:
        if waker is not None:
            waker.close()
        _teardown(node)
        for sig, handler in previous.items():
            if sig != signal.SIGINT:        # _teardown keeps a late Ctrl-C away
                signal.signal(sig, handler)
    if stop.is_set():
        _exit_now()


def idle_wake(executor) -> float:
    """The longest wait of ``executor``'s idle spin_once: IDLE_WAKE when a Wake can end it
    (rclpy's Python executors), else WAKE_PERIOD: the EventsExecutor has no guard conditions
    ("Guard conditions not supported") and its wake() does not end spin_once either."""
    return IDLE_WAKE if isinstance(executor, Executor) else WAKE_PERIOD


class Wake:
    """Ends the spin_once that ``node``'s executor is in now, from any thread.

    Executor.wake() does not: rclpy's _wait_for_ready_callbacks takes a woken wait that found
    no work for a change of entities, rebuilds its wait set and waits again until the
    spin_once's timeout (spin_once(3.0) woken after 0.5 s returned after 3.0 s, single- and
    multi-threaded). So with a long IDLE_WAKE every stop waited it out: a node's exit on
    SIGTERM, and Companion.destroy, whose 2 s join then gave up and left the teardown to run
    beside a live companion wait. A guard condition with a callback is work: the executor
    runs its empty callback and spin_once returns. Its own callback group, so a long callback
    of the node's default group does not hold it back."""

    def __init__(self, node: Node) -> None:
        self._guard = node.create_guard_condition(lambda: None,
                                                  MutuallyExclusiveCallbackGroup())

    def __call__(self) -> None:
        with contextlib.suppress(InvalidHandle):     # the node was destroyed: nothing to end
            self._guard.trigger()


def wake_for(node: Node, executor) -> Wake | None:
    """A Wake of ``node`` on ``executor``, or None for the EventsExecutor (no IDLE_WAKE)."""
    return Wake(node) if isinstance(executor, Executor) else None


class SignalWaker:
    """Ends the main thread's spin_once as soon as a signal arrives, so it can wait long.

    Python runs a signal's handler only when the main thread runs Python again, and a main
    thread in rcl_wait does so at the wait's timeout. signal.set_wakeup_fd has the C-level
    handler write the signal's number to a pipe at once; a thread reading it calls ``wake``
    (a Wake, or None: the EventsExecutor spins short), so the wait returns and the handler
    runs. Main thread only."""

    def __init__(self, wake: Callable[[], None] | None) -> None:
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        self._previous = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
        self._thread = threading.Thread(target=self._run, args=(wake,), daemon=True,
                                        name='signal_waker')
        self._thread.start()

    def _run(self, wake) -> None:
        with contextlib.suppress(OSError):
            while os.read(self._read, 64) and wake is not None:
                wake()

    def close(self) -> None:
        signal.set_wakeup_fd(self._previous)
        os.close(self._write)               # the reader's read returns b'': it ends
        self._thread.join(timeout=1.0)
        os.close(self._read)


def die_with_launcher() -> None:
    """A node started by api.launcher gets SIGTERM when the launcher dies (Linux), so no
    orphan outlives it; if the launcher is gone already, the node exits now."""
    launcher = os.environ.get(LAUNCHER_PID_ENV, '')
    if not launcher.isdigit():
        return
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != int(launcher):
        sys.exit(f'the launcher (pid {launcher}) that started this node is gone')


def _exit_now() -> None:
    """Exit 0 at once after a stop's teardown, skipping the interpreter's finalization.

    Everything a node stores is written and closed by then (goals ended, node destroyed, rclpy
    shut down). The finalization that follows (module teardown, the destructors of the
    extension modules' objects) took 0.4-2.3 s alone on an idle-ish machine, and under `up`'s
    Ctrl-C, with nine nodes finalizing at once on two loaded cores, it outlasted the 6 s before
    SIGTERM: four nodes ended with -15, their teardown dumps showing the main thread with no
    Python frame left (issue 31 item 3)."""
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    with contextlib.suppress(Exception):     # C stdio (rcutils' console output)
        ctypes.CDLL(None).fflush(None)
    os._exit(0)


def _stop_handler(stop: threading.Event):
    """SIGINT / SIGTERM: ask the node to stop, and every wait to give up."""
    def on_signal(_signum, _frame) -> None:
        stop.set()
        _stopping.set()
    return on_signal


def _finish_work_in_flight(executor, context) -> None:
    """Every wait for an answer gives up now (Stopping), so a callback that waits on the robot
    ends the way a lost robot makes it end (store what it has, abort its goal). The executor
    keeps spinning, so goal states, results and responses still go out, until none of that
    work is left or STOP_GRACE s have passed; a node that had a goal running then goes on
    answering for RESULT_LINGER s (a result asked for again)."""
    _stopping.set()
    # the callbacks a MultiThreadedExecutor is running now (a single-threaded one runs its
    # callbacks inside spin_once: none is running between two calls); later timer and
    # subscription callbacks are run meanwhile but not waited for
    in_flight = [f for f in list(getattr(executor, '_futures', ())) if not f.done()]
    deadline = time.monotonic() + STOP_GRACE

    def busy() -> bool:
        return not all(f.done() for f in in_flight) or _queued(executor)

    goal_running = _queued(executor)       # not a timer or message callback in flight
    while context.ok() and time.monotonic() < deadline and busy():
        executor.spin_once(timeout_sec=WAKE_PERIOD)
    if goal_running:        # its result may be asked for again
        linger = time.monotonic() + RESULT_LINGER
        while context.ok() and time.monotonic() < linger:
            executor.spin_once(timeout_sec=WAKE_PERIOD)
    if context.ok() and busy():     # where it waits, in the node's log
        print(f'work still in flight {STOP_GRACE:.0f} s after the stop, torn down under it; '
              'every thread:', file=sys.stderr, flush=True)
        faulthandler.dump_traceback(all_threads=True)


def _queued(executor) -> bool:
    """Whether the executor holds work a callback handed it that is not done: a goal still
    executing, or the result response its end queued. Without waiting for the latter a goal
    aborted by the stop never reached its client (the server was destroyed first, "Failed to
    send result response")."""
    return any(entity is None and not task.done()
               for task, entity, _ in list(getattr(executor, '_tasks', ())))


def _teardown(node: Node | None) -> None:
    """Destroy the node and shut rclpy down, deaf to Ctrl-C meanwhile; a teardown that hangs
    is ended by the TeardownWatchdog (within STOP_BOUND of the stop, before a launcher's
    SIGTERM), or sooner by a SIGTERM: from here on SIGTERM has its default action (the process
    ends at once, -15). A Python handler would never run while rclpy's C++ destroy holds the
    GIL: that hang (Fast DDS deleting the node) outlasted `up`'s SIGTERM when it came 6 s after
    its Ctrl-C, and its SIGKILL 2 s later ended the node with -9 (fresh-clone run 19,
    user_frame_solver, load 9). The node's work has ended by then: what it stores is stored.

    The EventsExecutor stops on SIGINT by itself, so the KeyboardInterrupt Python raises for
    the same signal can come later, in the middle of destroy_node (exit code 130 instead of 0,
    seen here); ignoring SIGINT from here on drops it.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # a node that outlived its teardown was killed (-9) twice in test suites, with nothing in
    # its log; if it happens again, the log shows where each thread stood (not cancelled: it
    # fires only while the process is still alive, in the teardown or at interpreter exit)
    faulthandler.dump_traceback_later(TEARDOWN_DUMP)
    watchdog = TeardownWatchdog()
    if node is not None:
        destroy(node)
    rclpy.try_shutdown()
    watchdog.cancel()


def destroy(node: Node) -> None:
    """``node.destroy_node()`` after destroying its action servers and clients.

    rclpy's destroy_node leaves them (its waitables), and each holds the node's handle, so the
    rmw node outlived it and with it the process's DDS participant: a process ending in
    os._exit (_exit_now) then left its Fast DDS shared-memory segments in /dev/shm, 16 MB each
    with config/fastdds_large_images.xml (2 per process of five node kinds; a day of test runs
    filled /dev/shm's 24 GB and the machine ran out of memory)."""
    for waitable in list(node.waitables):
        with contextlib.suppress(Exception):    # one that cannot be destroyed keeps the rest
            waitable.destroy()
    node.destroy_node()


class TeardownWatchdog:
    """Ends the process (exit 0) if it is still running TEARDOWN_EXIT s from its start; cancel
    it when the teardown is done. For a process whose work has ended and whose rclpy teardown
    is all that is left.

    Two timers: a Python one that says so on stderr first, and a native one EXIT_BACKSTOP s
    later that needs no Python: the hang seen is inside rclpy's C++ destroy of the node (Fast
    DDS deleting the participant) with the GIL held, where no Python thread runs (a suite's
    joint_state_monitor stopped by SIGINT hung there, its stacks dumped at TEARDOWN_DUMP s,
    the Python timer silent, until the launcher's SIGKILL)."""

    EXIT_BACKSTOP = 1.0     # [s] after TEARDOWN_EXIT

    def __init__(self) -> None:
        self._timer = threading.Timer(TEARDOWN_EXIT, _teardown_hung)
        self._timer.daemon = True
        self._timer.start()
        self._native = native_exit_timer(TEARDOWN_EXIT + self.EXIT_BACKSTOP)

    def cancel(self) -> None:
        self._timer.cancel()
        self._native.cancel()


# [s] the longest a node takes from a stop signal to its exit: its work's grace, then a
# teardown that the watchdog's native timer ends at worst. A launcher waits longer than this
# before its SIGTERM, so a node whose rclpy teardown hangs still ends by itself, with exit 0.
STOP_BOUND = STOP_GRACE + RESULT_LINGER + TEARDOWN_EXIT + TeardownWatchdog.EXIT_BACKSTOP


def _teardown_hung() -> None:
    print(f'teardown still running after {TEARDOWN_EXIT:g} s (rclpy destroy_node; stacks '
          'above): exiting', file=sys.stderr, flush=True)
    os._exit(0)


class _SigEvent(ctypes.Structure):
    """glibc's struct sigevent (x86-64 and aarch64 Linux: 64 bytes) for SIGEV_THREAD."""
    _fields_ = [('value', ctypes.c_void_p), ('signo', ctypes.c_int), ('notify', ctypes.c_int),
                ('function', ctypes.c_void_p), ('attribute', ctypes.c_void_p),
                ('_pad', ctypes.c_int * 8)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [('interval_s', ctypes.c_long), ('interval_ns', ctypes.c_long),
                ('value_s', ctypes.c_long), ('value_ns', ctypes.c_long)]


class NativeExitTimer:
    """A POSIX timer whose expiry runs libc's _exit(0) on a thread glibc starts: no Python, no
    GIL (timer_create with SIGEV_THREAD, its function _exit and its value 0, the exit code)."""

    SIGEV_THREAD, CLOCK_MONOTONIC = 2, 1

    def __init__(self, seconds: float) -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        self._delete = libc.timer_delete
        self._id = ctypes.c_void_p()
        event = _SigEvent(value=None, notify=self.SIGEV_THREAD,
                          function=ctypes.cast(libc._exit, ctypes.c_void_p).value)
        if libc.timer_create(self.CLOCK_MONOTONIC, ctypes.byref(event),
                             ctypes.byref(self._id)) != 0:
            raise OSError(ctypes.get_errno(), 'timer_create failed')
        spec = _ITimerSpec(0, 0, *split_ns(s_to_ns(seconds)))
        if libc.timer_settime(self._id, 0, ctypes.byref(spec), None) != 0:
            self.cancel()
            raise OSError(ctypes.get_errno(), 'timer_settime failed')

    def cancel(self) -> None:
        if self._id is not None:
            self._delete(self._id)
            self._id = None


class _NoTimer:
    def cancel(self) -> None:
        pass


def native_exit_timer(seconds: float) -> NativeExitTimer | _NoTimer:
    """A NativeExitTimer, or nothing where libc has no timer_create (the Python timer stays)."""
    try:
        return NativeExitTimer(seconds)
    except (OSError, AttributeError):
        return _NoTimer()


class Companion:
    """A hidden helper node with its own single-threaded executor (executor_kind()) on its own
    thread.

    rclpy's MultiThreadedExecutor handles well under 100 messages per second on two cores,
    while a SingleThreadedExecutor keeps up with 1 kHz. So every node here spins
    single-threaded, and what must keep running while one of its callbacks blocks (a 1 kHz
    subscription during a capture's hold window, the responses a service waits for) lives on
    a companion: same namespace, remappings and context, name with a leading underscore
    (hidden from node lists). Create subscriptions and clients on ``companion.node``.
    """

    def __init__(self, owner: Node, role: str) -> None:
        self.node = Node(f'_{owner.get_name()}_{role}', namespace=owner.get_namespace(),
                         context=owner.context, start_parameter_services=False)
        self.node.owner_name = owner.get_name()      # its process's own node (others_on_graph)
        self._executor = make_executor(owner.context)
        self._executor.add_node(self.node)
        self._wake = wake_for(self.node, self._executor)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True, name=role)
        self._thread.start()

    def _spin(self) -> None:
        period = idle_wake(self._executor)
        try:
            while self._running and self.node.context.ok():
                self._executor.spin_once(timeout_sec=period)
        except Exception as exc:  # noqa: BLE001 - mostly: the context was shut down under us
            if self._running and self.node.context.ok():   # no: a callback raised
                self.node.get_logger().error(
                    f'{self._thread.name}: stopped by an exception in a callback: {exc!r}')

    def run_action(self, client, goal, accept_timeout: float, result_timeout: float):
        """Send ``goal`` from any thread and block until its result; None if rejected;
        ServerLost when its server node exits, restarts or leaves the graph meanwhile
        (ros.calls.ServerWatch), or answers that it does not know the goal (a result kept past
        the server's result_timeout, or a server that restarted: its answer's result would be
        a default one, error code 0 included).

        rclpy's ActionClient is not thread-safe: a goal response can arrive on this executor
        before send_goal_async (called from another thread) has registered its sequence
        number, and is then dropped ("Ignoring unexpected goal response") and the call hangs.
        So sending and asking for the result both happen on the companion's own thread.
        """
        from cobot_calib_ros.ros.calls import ServerWatch
        from cobot_calib_ros.ros.suite_nodes import suite_watch
        suite_watch(self.node)      # the launcher's news of node exits, from before the goal
        sent_at = time.time()
        sent = self.send_goal(client, goal, accept_timeout)
        if sent is None:
            return None
        watch = ServerWatch(self.node, client, sent_at)     # its server exits: goal lost
        answer = wait(sent[1], result_timeout, watch.ended)
        if answer.status == GoalStatus.STATUS_UNKNOWN:
            raise ServerLost(f'{client._action_name}: the server does not know the goal (it '
                             'restarted, or kept its result less long than this wait)')
        return answer.result

    def send_goal(self, client, goal, accept_timeout: float):
        """Send ``goal`` on the companion's thread (:meth:`run_action` says why): its goal
        handle and the future of its result, or None if the server rejected it."""
        handle = wait(wait(self.submit(client.send_goal_async, goal), accept_timeout),
                      accept_timeout)
        if not handle.accepted:
            return None
        return handle, wait(self.submit(handle.get_result_async), accept_timeout)

    def submit(self, call, *args):
        """Run ``call(*args)`` on the companion's thread; the task (a future)."""
        return self._executor.create_task(call, *args)

    def destroy(self) -> None:
        # Stop the spinning thread before shutting its executor down: Executor.shutdown()
        # destroys the guard condition a concurrent wait may still hold (a segfault at exit).
        self._running = False
        if self._wake is not None:
            self._wake()                    # out of its spin_once now
        self._thread.join(timeout=2.0)      # still running after: a blocked callback
        if self._thread.is_alive():
            return                      # still blocked: leave the rest to process exit
        self._executor.shutdown(timeout_sec=1.0)
        destroy(self.node)


def log_info(logger, message: str) -> None:
    """``logger.info(message)`` for hot paths: same output, same /rosout, no filters.

    rclpy's logger finds its caller with inspect.getframeinfo, which scans every loaded module
    (1-3 ms per call here, more than a whole calibration); the caller's frame is enough.
    """
    if not logger.is_enabled_for(LoggingSeverity.INFO):
        return
    caller = sys._getframe(1)
    _rclpy.rclpy_logging_rcutils_log(LoggingSeverity.INFO, logger.name, message,
                                     caller.f_code.co_name, caller.f_code.co_filename,
                                     caller.f_lineno)


def stopping() -> bool:
    """Whether this process is shutting down (Ctrl-C, SIGTERM): a procedure stops at its next
    step, as if its goal were cancelled, and its goal ends aborted."""
    return _stopping.is_set()


def until(ready: Callable[[], bool], timeout: float) -> bool:
    """Look at ``ready()`` every WAKE_PERIOD until it is True (True) or ``timeout`` [s] passed
    (False); raises Stopping as soon as the process shuts down. For a server or service to
    appear: rclpy's wait_for_server / wait_for_service sleep through a shutdown."""
    deadline = time.monotonic() + timeout
    while not ready():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        pause(min(WAKE_PERIOD, remaining))
    return True


DISCOVERY_WAIT = 30.0     # [s] for servers on a domain where other nodes are seen


def absent_after(ready: dict[str, Callable[[], bool]], timeout: float,
                 graph=None) -> list[str]:
    """The names in ``ready`` whose check is still False after up to ``timeout`` s (one wait
    for all, ended as soon as all are True): the servers a call needs that are not on the
    graph. Raises Stopping as until does.

    ``graph``: the caller's rclpy node. When it sees other nodes by then (others_on_graph), a
    suite is there and is still being discovered, so the servers are waited for up to
    DISCOVERY_WAIT s in all: on loaded CI runs a new process had not yet seen
    kinematic_identifier 5 s after `up` said every node answered. An empty domain is said
    after ``timeout``.
    """
    def all_ready() -> bool:
        return all(is_ready() for is_ready in ready.values())

    if not until(all_ready, timeout) and graph is not None and others_on_graph(graph):
        until(all_ready, max(0.0, DISCOVERY_WAIT - timeout))
    return [name for name, is_ready in ready.items() if not is_ready()]


def others_on_graph(node) -> bool:
    """Whether ``node`` sees a node on the graph other than itself, the node it is a companion
    of, and companions (named with a leading underscore)."""
    own = {node.get_name(), getattr(node, 'owner_name', '')}
    with contextlib.suppress(Exception):        # a graph query during shutdown
        return any(name not in own and not name.startswith('_')
                   for name in node.get_node_names())
    return False


def pause(seconds: float) -> None:
    """Sleep ``seconds``, or raise Stopping as soon as the process shuts down."""
    if _stopping.wait(seconds):
        raise Stopping('the node is shutting down')


class ServerLost(TimeoutError):
    """A wait ended because the server that was to answer exited, restarted or is gone."""


LOST_CHECK_PERIOD = 0.25    # [s] between two looks of ``wait`` at its ``lost`` check


def wait(future, timeout: float, lost: Callable[[], str] | None = None):
    """Block this thread until ``future`` is done (another executor completes it); its result.

    Raises TimeoutError after ``timeout`` [s], Stopping as soon as the process shuts down,
    ServerLost when ``lost()`` (asked every LOST_CHECK_PERIOD s) says why the answer will
    never come.
    """
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not _wait_event(done, timeout, lost):
        raise TimeoutError(f'no answer within {timeout:.0f} s')
    return future.result()


def wait_answer(send: Callable[[], object], timeout: float, ask_again: float,
                forget: Callable[[object], None] = lambda future: None):
    """:func:`wait` for a query: ``send()`` (its future) again every ``ask_again`` [s] while
    none is answered, up to ``timeout`` [s]; the first answer's result. A server that has not
    yet matched a new client's reply reader drops its answer (ros.calls.ASK_AGAIN): a
    tcp_calibrator's first capture_joints got none in 10 s in a fresh-clone test run.
    ``forget(future)`` for each one left unanswered."""
    done = threading.Event()
    deadline = time.monotonic() + timeout
    sent = []
    try:
        while (remaining := deadline - time.monotonic()) > 0:
            future = send()
            future.add_done_callback(lambda _: done.set())
            sent.append(future)
            if _wait_event(done, min(ask_again, remaining)):
                return next(f for f in sent if f.done()).result()
        raise TimeoutError(f'no answer within {timeout:.0f} s')
    finally:
        for future in sent:
            if not future.done():
                forget(future)


def _wait_event(done: threading.Event, timeout: float,
                lost: Callable[[], str] | None = None) -> bool:
    """Whether ``done`` was set within ``timeout`` [s]; Stopping and ServerLost as in
    :func:`wait`."""
    deadline = time.monotonic() + timeout
    looked = time.monotonic()
    while not done.wait(min(WAKE_PERIOD, max(0.0, deadline - time.monotonic()))):
        if _stopping.is_set():
            raise Stopping('the node is shutting down')
        if lost is not None and time.monotonic() - looked >= LOST_CHECK_PERIOD:
            looked = time.monotonic()
            why = lost()
            if why:
                raise ServerLost(why)
        if time.monotonic() >= deadline:
            return False
    return True
