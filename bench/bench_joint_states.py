"""joint_states at 1 kHz between processes, and the capture_joints round trip.

mock_robot and joint_state_monitor run as two processes (launcher.Suite) on a private domain.
Over BENCH_JOINT_STATES_SECONDS (default 60 s) of flow, the monitor's own /diagnostics counters
give the received rate and the fraction missing by header stamp (difference of two snapshots).

The bench process also subscribes to joint_states to count what the publisher achieved without
relying on the monitor. That is a third participant on a 2-core machine and adds load (its spin
loop costs CPU, and the publisher now serves two reliable readers): it takes the messages as raw
CDR bytes (no deserialisation) to keep that small, and BENCH_JOINT_STATES_OWN_SUB=0 turns it off
to compare. Its count is a lower bound on the publisher's rate (equal when it loses nothing).
"""
from __future__ import annotations

from dataclasses import dataclass
import os
import struct
import time

from cobot_calib_msgs.srv import CaptureJoints
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros.api import launcher

NOMINAL_RATE = 1000.0       # [Hz] sawyer_close joint_states_hz
CAPTURE_CALLS = 50
CAPTURE_WARMUP = 5          # not counted
CAPTURE_DURATION = 0.05     # [s] hold window per capture
MONITOR = 'joint_state_monitor'
NODES = ('mock_robot', MONITOR)
CDR_STAMP = struct.Struct('<iI')  # header.stamp after the 4-byte encapsulation header (LE)


@dataclass(frozen=True)
class Snapshot:
    """Counters at the moment one monitor diagnostics message arrived in the bench."""

    t: float                # bench monotonic time [s]
    received: int           # monitor: accepted joint_states
    missing: int            # monitor: missing by header stamp
    malformed: int          # monitor: dropped_* summed
    own_count: int          # bench subscriber: messages
    own_missing: int        # bench subscriber: missing by header stamp
    cpu: dict[str, float]   # process CPU seconds by name ('bench' = this process)


class Probe:
    """Counts joint_states itself and records a Snapshot per monitor diagnostics message."""

    def __init__(self, ros: Ros, pids: dict[str, int], own_sub: bool) -> None:
        self.snapshots: list[Snapshot] = []
        self._pids = dict(pids, bench=os.getpid())
        self._count = 0
        self._missing = 0
        self._last_stamp: float | None = None
        ros.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.joint_sub = None
        if own_sub:
            self.joint_sub = ros.node.create_subscription(
                JointState, 'joint_states', self._on_joint_state,
                QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True)

    def _on_joint_state(self, data: bytes) -> None:
        sec, nanosec = CDR_STAMP.unpack_from(data, 4)
        stamp = sec + nanosec * 1e-9
        if self._last_stamp is not None:
            self._missing += max(0, round((stamp - self._last_stamp) * NOMINAL_RATE) - 1)
        self._last_stamp = stamp
        self._count += 1

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id != 'joint_states':
                continue
            values = {kv.key: int(kv.value) for kv in status.values}
            self.snapshots.append(Snapshot(
                time.monotonic(), values['received'], values['missing_by_stamp'],
                sum(v for k, v in values.items() if k.startswith('dropped_')),
                self._count, self._missing,
                {n: benchlib.process_cpu_seconds(p) for n, p in self._pids.items()}))

    def next_snapshot(self, ros: Ros, after: float, timeout: float = 5.0) -> Snapshot:
        """The first snapshot taken at or after monotonic time `after`."""
        def found() -> bool:
            return bool(self.snapshots) and self.snapshots[-1].t >= after
        if not ros.spin_until(found, max(0.0, after - time.monotonic()) + timeout):
            raise BenchFailed(f'no /diagnostics from {MONITOR} for {timeout:.0f} s')
        return next(s for s in self.snapshots if s.t >= after)


def flow_figures(a: Snapshot, b: Snapshot, own_sub: bool) -> Figures:
    """Rates, missing fractions and CPU use between two snapshots."""
    interval = b.t - a.t
    received, missing = b.received - a.received, b.missing - a.missing
    figures: Figures = {
        'joint_states_interval': (interval, 's'),
        'joint_states_received_rate': (received / interval, 'Hz'),
        'joint_states_drop_fraction': (100.0 * missing / max(1, received + missing), '%'),
        'joint_states_missing_by_stamp': (missing, 'count'),
        'joint_states_dropped_malformed': (b.malformed - a.malformed, 'count'),
    }
    if own_sub:
        own, own_missing = b.own_count - a.own_count, b.own_missing - a.own_missing
        figures['joint_states_publisher_rate'] = (own / interval, 'Hz')
        figures['joint_states_bench_sub_drop_fraction'] = (
            100.0 * own_missing / max(1, own + own_missing), '%')
        # missing_by_stamp also counts publisher stalls (a late tick, then a catch-up burst)
        # as missing; the monitor's count against the bench subscriber's is a lower bound on
        # what the monitor really lost (exact when the bench subscriber lost nothing).
        figures['joint_states_monitor_loss_vs_bench_sub'] = (
            100.0 * (1.0 - received / max(1, own)), '%')
    for name in a.cpu:
        key = 'monitor' if name == MONITOR else name
        figures[f'joint_states_cpu_{key}'] = (
            100.0 * (b.cpu[name] - a.cpu[name]) / interval, '% of one core')
    return figures


def wait_flowing(ros: Ros, suite: launcher.Suite, probe: Probe) -> None:
    """Wait until the monitor counts joint_states (mock_robot starts slower than the monitor)."""
    def flowing() -> bool:
        return bool(suite.failed()) or any(s.received > 0 for s in probe.snapshots)
    ros.spin_until(flowing, benchlib.STARTUP_TIMEOUT)
    if suite.failed() or not flowing():
        raise BenchFailed(f'{MONITOR} received no joint_states within '
                          f'{benchlib.STARTUP_TIMEOUT:.0f} s; exited nodes: '
                          f'{suite.failed() or "none"} (logs: {suite.log_dir})')


def measure_flow(ros: Ros, suite: launcher.Suite, seconds: float) -> Figures:
    """Let joint_states flow for `seconds` and compare the counters at both ends."""
    own_sub = os.environ.get('BENCH_JOINT_STATES_OWN_SUB', '1') != '0'
    probe = Probe(ros, {n: p.pid for n, p in suite.processes.items()}, own_sub)
    wait_flowing(ros, suite, probe)
    start = probe.next_snapshot(ros, time.monotonic())
    end = probe.next_snapshot(ros, start.t + seconds - 0.5)
    if probe.joint_sub is not None:
        ros.node.destroy_subscription(probe.joint_sub)  # keep it out of the capture figures
    return flow_figures(start, end, own_sub)


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


def run() -> Figures:
    """The joint_states flow and capture_joints figures."""
    seconds = float(os.environ.get('BENCH_JOINT_STATES_SECONDS', '60'))
    specs = launcher.suite_specs('sawyer_close', NODES)
    with benchlib.private_domain() as (domain, env), \
            benchlib.running_suite('joint_states', specs, env) as suite, \
            benchlib.ros_node('bench_joint_states', domain) as ros:
        capture = ros.node.create_client(CaptureJoints, 'capture_joints')
        benchlib.wait_for_service(ros, suite, MONITOR, capture)
        figures = measure_flow(ros, suite, seconds)
        figures.update(measure_capture(ros, capture))
        if suite.failed():
            raise BenchFailed(f'node exited during the bench: {suite.failed()}', figures)
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
