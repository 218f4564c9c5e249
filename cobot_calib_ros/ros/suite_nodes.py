"""The suite's node processes as its launcher sees them: a latched topic every client watches.

`cobot-calib up` holds its nodes' PIDs, so it knows at once when one exits (a crash, a kill -9)
and when it starts again; DDS learns it only when the dead participant's lease runs out (Fast
DDS: 20 s; Fast-DDS#6502 advises against shortening it). The launcher publishes each node's
process on ``suite/nodes`` (relative: a namespaced suite's own), reliable and transient local
(latched), again at every start and exit: diagnostic_msgs/DiagnosticArray, one status per node
named by its full name ('/tcp_calibrator'), level OK while it runs, ERROR once it exited, the
values ``pid``, ``starts``, ``running``, ``started``, and ``exit_code`` and ``exited`` of its
last exit (times: wall-clock seconds, as text). A client waiting on a goal
(ros.calls.ServerWatch) asks SuiteWatch whether the goal's node exited after the goal was
sent: that goal is lost, said within the launcher's watch period.
A node that `up` did not start (a real robot's driver) is not on the topic; the graph tells.
"""
from __future__ import annotations

from dataclasses import dataclass
import signal
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from cobot_calib_ros.ros.qos import LATCHED

TOPIC = 'suite/nodes'


@dataclass(frozen=True)
class NodeProcess:
    """One node process of the suite. Times are wall-clock [s] (time.time), comparable
    between processes of one machine."""

    name: str                       # full node name, '/ns/name'
    pid: int
    starts: int                     # 1 at the first start, +1 at every restart
    started: float
    running: bool = True
    exit_code: int | None = None    # of the last exit (kept after a restart); None: none yet
    exited: float | None = None     # the last exit's time (kept after a restart)
    left_down: bool = False         # not restarted again

    def how_it_ended(self) -> str:
        """'killed by SIGKILL', 'exited with code 1', ... (of the last exit)."""
        code = self.exit_code
        if code is None:
            return 'exited'
        if code < 0:
            try:
                return f'killed by {signal.Signals(-code).name}'
            except ValueError:
                return f'killed by signal {-code}'
        return f'exited with code {code}'


def to_message(processes: list[NodeProcess], stamp) -> DiagnosticArray:
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    for p in processes:
        values = {'pid': p.pid, 'starts': p.starts, 'started': f'{p.started:.3f}',
                  'running': 'true' if p.running else 'false',
                  'exit_code': '' if p.exit_code is None else p.exit_code,
                  'exited': '' if p.exited is None else f'{p.exited:.3f}',
                  'left_down': 'true' if p.left_down else 'false'}
        state = 'running' if p.running else \
            f'{p.how_it_ended()}{", left down" if p.left_down else ""}'
        msg.status.append(DiagnosticStatus(
            level=DiagnosticStatus.OK if p.running else DiagnosticStatus.ERROR, name=p.name,
            message=state, hardware_id=str(p.pid),
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()]))
    return msg


def from_message(msg: DiagnosticArray) -> dict[str, NodeProcess]:
    """Full node name -> NodeProcess; statuses that do not read are left out."""
    out = {}
    for status in msg.status:
        v = {kv.key: kv.value for kv in status.values}
        try:
            out[status.name] = NodeProcess(
                status.name, int(v['pid']), int(v['starts']), float(v['started']),
                v.get('running') == 'true', int(v['exit_code']) if v.get('exit_code') else None,
                float(v['exited']) if v.get('exited') else None,
                v.get('left_down') == 'true')
        except (KeyError, ValueError):
            continue
    return out


class SuitePublisher:
    """The launcher's side: ``started``, ``exited`` and ``left_down`` as they happen; each
    publishes every node's process (latched)."""

    def __init__(self, node) -> None:
        self._node = node
        self._publisher = node.create_publisher(DiagnosticArray, TOPIC, LATCHED)
        self._processes: dict[str, NodeProcess] = {}

    def started(self, name: str, pid: int) -> None:
        old = self._processes.get(name)
        self._processes[name] = NodeProcess(
            name, pid, old.starts + 1 if old else 1, time.time(), True,
            old.exit_code if old else None, old.exited if old else None)
        self._publish()

    def exited(self, name: str, code: int, left_down: bool = False) -> None:
        old = self._processes.get(name)
        if old is None:
            return
        self._processes[name] = NodeProcess(name, old.pid, old.starts, old.started, False,
                                            code, time.time(), left_down)
        self._publish()

    def _publish(self) -> None:
        self._publisher.publish(to_message(list(self._processes.values()),
                                           self._node.get_clock().now().to_msg()))


class SuiteWatch:
    """A client's side: the latest ``suite/nodes`` (none if no launcher publishes it)."""

    def __init__(self, node) -> None:
        self._lock = threading.Lock()
        self._processes: dict[str, NodeProcess] = {}
        self._subscription = node.create_subscription(DiagnosticArray, TOPIC, self._on_message,
                                                      LATCHED)

    def _on_message(self, msg: DiagnosticArray) -> None:
        processes = from_message(msg)
        with self._lock:
            self._processes = processes

    def process(self, name: str) -> NodeProcess | None:
        with self._lock:
            return self._processes.get(name)

    def exit_since(self, name: str, since: float) -> NodeProcess | None:
        """The process of node ``name`` (full name) if it exited at or after ``since`` (wall
        clock [s]), else None."""
        p = self.process(name)
        return p if p is not None and p.exited is not None and p.exited >= since else None


def suite_watch(node) -> SuiteWatch:
    """The node's SuiteWatch, made at the first call (one subscription per node)."""
    watch = getattr(node, '_cobot_suite_watch', None)
    if watch is None:
        watch = SuiteWatch(node)
        node._cobot_suite_watch = watch
    return watch
