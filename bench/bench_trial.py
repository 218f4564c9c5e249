"""Wall time of 30-cycle, 5-point ISO 9283 trials in fast mode (the cell's time_scale).

The whole suite runs as separate processes on a private domain; the bench sends run_trial goals
and times each from goal to result: a reference trial (5 probe visits per cycle) and a rigid
trial (10: the calibration pass that fits M_n, then the measurement pass). Trial set-up (touch
and capture each marker, find the offsets F_i) is included.
"""
from __future__ import annotations

import time

from cobot_calib_msgs.action import RunTrial
from rclpy.action import ActionClient

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.client import CallError, run_action, wait_for_suite

CYCLES = 30
METHODS = ('reference', 'rigid')


def run() -> Figures:
    figures: Figures = {}
    with benchlib.private_domain() as (domain, env):
        specs = launcher.suite_specs('sawyer_close', overrides={
            'repeatability_trial': {'data_dir': env['COBOT_CALIB_DATA']}})
        with benchlib.running_suite('trial', specs, env) as suite, \
                benchlib.ros_node('bench_trial', domain) as ros:
            try:
                wait_for_suite(ros.node, benchlib.STARTUP_TIMEOUT, ros.executor)
                client = ActionClient(ros.node, RunTrial, 'run_trial')
                for method in METHODS:
                    start = time.perf_counter()
                    _, result = run_action(ros.node, client,
                                           RunTrial.Goal(method=method, cycles=CYCLES),
                                           600.0, executor=ros.executor)
                    if result.error_code != RunTrial.Result.SUCCESS:
                        raise BenchFailed(f'{method} trial: {result.message}', figures)
                    figures[f'trial_{method}_30x5_wall'] = (time.perf_counter() - start, 's')
                    figures[f'trial_{method}_rp_all'] = (result.statistics.rp_all_mm, 'mm')
            except CallError as exc:
                raise BenchFailed(f'{exc} (logs: {suite.log_dir})', figures)
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
