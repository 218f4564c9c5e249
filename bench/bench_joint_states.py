"""joint_states at 1 kHz between processes, and the capture_joints round trip, per executor.

For each node executor (benchlib.executors()), mock_robot and joint_state_monitor run as two
processes on a private domain and joint_states flow for BENCH_JOINT_STATES_SECONDS (default 60 s)
of stamp time. Both nodes' /diagnostics carry a count before the latest whole second of stamp
time (core.sensors.joint_buffer.StampMarks): for two seconds a and b that both reported,
`joint_states_lost` = published - received between them, exactly, with start-up and shut-down
outside (goal: 0). Beside it, what stamp gaps say: `joint_states_stamp_gaps_missing_percent`
(the monitor's missing_by_stamp: publisher stalls and losses alike) and
`joint_states_publisher_stamp_gaps_missing_percent` (mock_robot's own stalls).

The bench process also takes joint_states, as raw CDR bytes (no deserialisation, to keep its
load small; BENCH_JOINT_STATES_OWN_SUB=0 turns it off): their stamps give the publisher's
cadence, `joint_states_publish_gap_p99_ms`, and its own exact loss. It is a third participant on
a 2-core machine (the publisher then serves two reliable readers). CPU figures are % of one
core of each process over the same interval, from /proc/<pid>/stat; the load average shows how
busy the machine was. `joint_states_lost` without a suffix is spin.DEFAULT_EXECUTOR's.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import os
import struct
import time

from cobot_calib_msgs.srv import CaptureJoints
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.time import NS_PER_S

CAPTURE_CALLS = 50
CAPTURE_WARMUP = 5          # not counted
CAPTURE_DURATION = 0.05     # [s] hold window per capture
MONITOR = 'joint_state_monitor'
ROBOT = 'mock_robot'
NODES = (ROBOT, MONITOR)
STATUS = {ROBOT: 'mock_robot: health', MONITOR: 'joint_state_monitor: health'}
COUNT_BEFORE_MARK = {ROBOT: 'published_before_mark', MONITOR: 'received_before_mark'}
SETTLE_S = 2.0              # [s] of flow before the measured interval starts
CDR_STAMP = struct.Struct('<iI')  # header.stamp after the 4-byte encapsulation header (LE)


@dataclass(frozen=True)
class Snapshot:
    """One node's diagnostics values when they arrived in the bench, with CPU times then."""

    t: float                # bench monotonic time [s]
    values: dict[str, str]
    cpu: dict[str, float]   # process CPU seconds by name ('bench' = this process)

    @property
    def mark(self) -> tuple[int, int]:
        """(whole stamp second, messages before it) of the node's StampMarks."""
        key = next(k for k in self.values if k.endswith('_before_mark'))
        return int(self.values['mark_stamp_s']), int(self.values[key])

    def number(self, key: str) -> float:
        return float(self.values[key])


@dataclass
class Probe:
    """Snapshots of both nodes' /diagnostics, and the stamps [ns] of joint_states taken raw."""

    pids: dict[str, int]
    snapshots: dict[str, list[Snapshot]] = field(default_factory=lambda: {n: [] for n in NODES})
    stamps_ns: list[int] = field(default_factory=list)

    def attach(self, ros: Ros, own_sub: bool) -> list:
        """Subscribe; the subscriptions (to destroy when done)."""
        subs = [ros.node.create_subscription(DiagnosticArray, '/diagnostics',
                                             self._on_diagnostics, 50)]
        if own_sub:
            subs.append(ros.node.create_subscription(
                JointState, 'joint_states', self._on_joint_state,
                QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True))
        return subs

    def _on_joint_state(self, data: bytes) -> None:
        sec, nanosec = CDR_STAMP.unpack_from(data, 4)
        self.stamps_ns.append(sec * NS_PER_S + nanosec)   # a CDR stamp, read raw

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            node = next((n for n, name in STATUS.items() if status.name == name), None)
            if node is not None:
                cpu = {n: benchlib.process_cpu_seconds(p) for n, p in self.pids.items()}
                self.snapshots[node].append(Snapshot(
                    time.monotonic(), {kv.key: kv.value for kv in status.values}, cpu))

    def flowing(self) -> bool:
        return all(s and s[-1].mark[1] > 0 for s in self.snapshots.values())


def marks(snapshots: list[Snapshot], after: float) -> dict[int, Snapshot]:
    """The first snapshot of each marked second, among those taken after `after`."""
    first: dict[int, Snapshot] = {}
    for snap in snapshots:
        if snap.t >= after:
            first.setdefault(snap.mark[0], snap)
    return first


def common_interval(probe: Probe, after: float, seconds: float) -> tuple[int, int]:
    """Seconds a < b of stamp time both nodes marked, b - a as close to `seconds` as there is."""
    shared = sorted(set(marks(probe.snapshots[ROBOT], after))
                    & set(marks(probe.snapshots[MONITOR], after)))
    if len(shared) < 2:
        raise BenchFailed(f'{ROBOT} and {MONITOR} reported fewer than two common stamp seconds')
    a = shared[0]
    b = max(s for s in shared if s <= a + seconds) if shared[1] <= a + seconds else shared[1]
    return a, b


def loss_figures(probe: Probe, a: int, b: int, after: float) -> Figures:
    """Published, received and lost between stamp seconds a and b, and the rates."""
    pub = {s: snap.mark[1] for s, snap in marks(probe.snapshots[ROBOT], after).items()}
    recv = {s: snap.mark[1] for s, snap in marks(probe.snapshots[MONITOR], after).items()}
    published, received = pub[b] - pub[a], recv[b] - recv[a]
    return {
        'joint_states_lost': (published - received, 'count'),
        'joint_states_published': (published, 'count'),
        'joint_states_interval_s': (b - a, 's'),
        'joint_states_published_rate_hz': (published / (b - a), 'Hz'),
        'joint_states_received_rate_hz': (received / (b - a), 'Hz'),
    }


def stamp_gap_figures(probe: Probe, a: int, b: int, after: float) -> Figures:
    """What stamp gaps count as missing, at the monitor and at the publisher itself."""
    robot_a, robot_b = (marks(probe.snapshots[ROBOT], after)[s] for s in (a, b))
    mon_a, mon_b = (marks(probe.snapshots[MONITOR], after)[s] for s in (a, b))
    received = mon_b.number('received') - mon_a.number('received')
    missing = mon_b.number('missing_by_stamp') - mon_a.number('missing_by_stamp')
    published = robot_b.number('published') - robot_a.number('published')
    stalls = robot_b.number('stamp_gaps_missing') - robot_a.number('stamp_gaps_missing')
    dropped = sum(mon_b.number(k) - mon_a.number(k) for k in mon_b.values
                  if k.startswith('dropped_'))
    return {
        'joint_states_stamp_gaps_missing_percent': (
            100.0 * missing / max(1.0, received + missing), '%'),
        'joint_states_publisher_stamp_gaps_missing_percent': (
            100.0 * stalls / max(1.0, published + stalls), '%'),
        'joint_states_dropped_malformed': (dropped, 'count'),
    }


def cadence_figures(probe: Probe, a: int, b: int, after: float) -> Figures:
    """The publisher's cadence as the bench's raw subscriber saw it, and that one's loss."""
    stamps = np.asarray(probe.stamps_ns, dtype=np.int64)
    inside = stamps[(stamps >= a * NS_PER_S) & (stamps < b * NS_PER_S)]
    if len(inside) < 2:
        return {}
    gaps_ms = np.diff(inside) * 1e-6
    pub = {s: snap.mark[1] for s, snap in marks(probe.snapshots[ROBOT], after).items()}
    return {
        'joint_states_publish_gap_p99_ms': (float(np.percentile(gaps_ms, 99)), 'ms'),
        'joint_states_publish_gap_max_ms': (float(gaps_ms.max()), 'ms'),
        'joint_states_bench_sub_lost': (pub[b] - pub[a] - len(inside), 'count'),
    }


def cpu_figures(probe: Probe, a: int, b: int, after: float) -> Figures:
    """% of one core of each process between the monitor's reports of seconds a and b."""
    start, end = (marks(probe.snapshots[MONITOR], after)[s] for s in (a, b))
    interval = end.t - start.t
    names = {MONITOR: 'monitor', ROBOT: 'mock_robot', 'bench': 'bench_process'}
    return {f'{names[n]}_cpu_percent': (100.0 * (end.cpu[n] - start.cpu[n]) / interval,
                                        '% of one core') for n in start.cpu}


def wait_flowing(ros: Ros, suite: launcher.Suite, probe: Probe) -> None:
    """Until both nodes report joint_states counted (mock_robot starts slower)."""
    ros.spin_until(lambda: bool(suite.failed()) or probe.flowing(), benchlib.STARTUP_TIMEOUT)
    if suite.failed() or not probe.flowing():
        raise BenchFailed(f'joint_states not flowing within {benchlib.STARTUP_TIMEOUT:.0f} s; '
                          f'exited nodes: {suite.failed() or "none"} (logs: {suite.log_dir})')


def measure_flow(ros: Ros, suite: launcher.Suite, seconds: float) -> Figures:
    """Let joint_states flow for `seconds` of stamp time and compare both ends."""
    own_sub = os.environ.get('BENCH_JOINT_STATES_OWN_SUB', '1') != '0'
    probe = Probe(dict({n: p.pid for n, p in suite.processes.items()}, bench=os.getpid()))
    subs = probe.attach(ros, own_sub)
    wait_flowing(ros, suite, probe)
    ros.spin_for(SETTLE_S)
    after = time.monotonic()
    load_start = benchlib.load_average_1min()
    ros.spin_for(seconds + 2.5)     # the last whole second, and one diagnostics period more
    for sub in subs:
        ros.node.destroy_subscription(sub)      # keep them out of the capture figures
    a, b = common_interval(probe, after, seconds)
    figures = loss_figures(probe, a, b, after)
    for part in (stamp_gap_figures, cadence_figures, cpu_figures):
        figures.update(part(probe, a, b, after))
    figures['joint_states_load_average_1min'] = (
        0.5 * (load_start + benchlib.load_average_1min()), 'load')
    return figures


def measure_capture(ros: Ros, client) -> Figures:
    """Round trip of capture_joints with a short hold window, and its overhead over it."""
    request = CaptureJoints.Request(duration=CAPTURE_DURATION)
    for _ in range(CAPTURE_WARMUP):
        benchlib.timed_call(ros, client, request)
    times, refused = [], 0
    for _ in range(CAPTURE_CALLS):
        seconds, response = benchlib.timed_call(ros, client, request)
        times.append(seconds)
        refused += response.error_code != CaptureJoints.Response.SUCCESS
    figures = benchlib.percentiles_ms('capture_joints_roundtrip', times)
    figures.update(benchlib.percentiles_ms(
        'capture_joints_overhead', [t - CAPTURE_DURATION for t in times]))
    figures['capture_joints_refused'] = (refused, 'count')
    return figures


def run_executor(kind: str, seconds: float) -> Figures:
    """The flow and capture figures with every node on executor `kind`."""
    specs = launcher.suite_specs(paths.DEFAULT_CELL, NODES)
    with benchlib.private_domain() as (domain, env), \
            benchlib.running_suite(f'joint_states_{kind}', specs,
                                   benchlib.executor_env(env, kind)) as suite, \
            benchlib.ros_node('bench_joint_states', domain) as ros:
        capture = ros.node.create_client(CaptureJoints, 'capture_joints')
        benchlib.wait_for_service(ros, suite, MONITOR, capture)
        figures = measure_flow(ros, suite, seconds)
        figures.update(measure_capture(ros, capture))
        if suite.failed():
            raise BenchFailed(f'node exited during the bench: {suite.failed()}', figures)
    return figures


def run() -> Figures:
    """The joint_states flow and capture_joints figures, for each executor."""
    seconds = float(os.environ.get('BENCH_JOINT_STATES_SECONDS', '60'))
    figures: Figures = {}
    for kind in benchlib.executors():
        try:
            figures.update(benchlib.suffixed(run_executor(kind, seconds), kind))
        except BenchFailed as exc:
            figures.update(benchlib.suffixed(exc.partial, kind))
            raise BenchFailed(f'{kind} executor: {exc}', figures) from exc
    default = f'joint_states_lost_{spin.DEFAULT_EXECUTOR}'
    if default in figures:
        figures['joint_states_lost'] = figures[default]
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
