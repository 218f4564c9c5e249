"""The node suite at rest: what `cobot-calib up` costs while nobody asks it for anything.

The whole suite (launcher.suite_specs of the default cell, as `up` starts it) runs on a private
domain; once joint_states and probe readings flow (api.client.wait_for_suite) and SETTLE_S more
have passed, each node process's CPU time is read from /proc over BENCH_IDLE_SECONDS (default
20) with nothing calling it and nothing subscribing to its outputs:

- ``idle_suite_cpu_percent``: all node processes together, % of one core (issue 23: 81 % on
  e6ccb73: mock_robot 32, joint_state_monitor 26, mock_camera 9, proximity_sensor 8,
  landmark_detector 5);
- ``idle_<node>_cpu_percent``: each node's share;
- ``idle_joint_states_rate_hz``: the rate mock_robot reached meanwhile (median of its
  /diagnostics; a starved publisher costs its subscribers less);
- ``idle_load_average_1min``: how busy the machine was (2 cores; above 2 processes wait).

mock_robot publishes 1 kHz joint_states (a real robot's driver would), joint_state_monitor
takes them all; the camera and the detector should rest (no one needs images; the bench's
node subscribes to /diagnostics only).
"""
from __future__ import annotations

import os
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.client import wait_for_suite

SETTLE_S = 5.0      # [s] after the suite is ready: discovery and start-up transients end


def run() -> Figures:
    seconds = float(os.environ.get('BENCH_IDLE_SECONDS', '20'))
    with benchlib.private_domain() as (domain, env), \
            benchlib.running_suite('idle', launcher.suite_specs(paths.DEFAULT_CELL),
                                   env) as suite, \
            benchlib.ros_node('bench_idle', domain) as ros:
        try:
            wait_for_suite(ros.node, benchlib.STARTUP_TIMEOUT, ros.executor)
        except Exception as exc:  # noqa: BLE001 - CallError, timeouts: the suite did not come up
            raise BenchFailed(f'the suite did not come up: {exc} (log: {suite.log_dir})')
        ros.spin_for(SETTLE_S)
        rates = []              # mock_robot's joint_states rate, as it reports it (1 Hz)

        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                if status.name == 'mock_robot: health':
                    values = {kv.key: kv.value for kv in status.values}
                    rates.append(float(values.get('publish_rate_hz', 'nan')))

        ros.node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
        pids = {name: p.pid for name, p in suite.processes.items()}
        start = {name: benchlib.process_cpu_seconds(pid) for name, pid in pids.items()}
        t0 = time.monotonic()
        ros.spin_for(seconds)
        elapsed = time.monotonic() - t0
        end = {name: benchlib.process_cpu_seconds(pid) for name, pid in pids.items()}
        if suite.failed():
            raise BenchFailed(f'nodes exited: {suite.failed()} (log: {suite.log_dir})')
    shares = {name: 100.0 * (end[name] - start[name]) / elapsed for name in pids}
    figures: Figures = {'idle_suite_cpu_percent': (sum(shares.values()), '% of one core')}
    figures.update({f'idle_{name}_cpu_percent': (value, '% of one core')
                    for name, value in sorted(shares.items(), key=lambda kv: -kv[1])})
    figures['idle_joint_states_rate_hz'] = (float(np.median(rates)) if rates else float('nan'),
                                            'Hz')
    figures['idle_load_average_1min'] = (benchlib.load_average_1min(), 'load')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
