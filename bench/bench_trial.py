"""Wall time of 30-cycle, 5-point ISO 9283 trials in fast mode (the cell's time_scale), per
node executor.

For each executor (benchlib.executors()) the whole suite runs as separate processes on a
private domain; the bench sends run_trial goals and times each from goal to result: a
reference trial (5 probe visits per cycle) and a rigid trial (10: the calibration pass that
fits M_n, then the measurement pass). Trial set-up (touch and capture each marker, find the
offsets F_i) is included. The trial drives every node (actions and services through
spin.Companion threads), so it is also the end-to-end check of each executor. The hold and
probe windows the trial retried (``_capture_retries``, ``_probe_retries``: 0 on an unloaded
machine, a stalling stream shows here) are counted too.
"""
from __future__ import annotations

import time

from cobot_calib_msgs.action import RunTrial

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import CallError, run_action
from cobot_calib_ros.api.client import wait_for_suite

CYCLES = 30
METHODS = ('reference', 'rigid')


def run_executor(kind: str) -> Figures:
    """Both trials with every node on executor `kind`."""
    figures: Figures = {}
    with benchlib.private_domain() as (domain, env):
        specs = launcher.suite_specs(paths.DEFAULT_CELL, overrides={
            'repeatability_trial': {'data_dir': env['COBOT_CALIB_DATA']}})
        with benchlib.running_suite(f'trial_{kind}', specs,
                                    benchlib.executor_env(env, kind)) as suite, \
                benchlib.ros_node('bench_trial', domain) as ros:
            try:
                wait_for_suite(ros.node, benchlib.STARTUP_TIMEOUT, ros.executor)
                client = ActionClient(ros.node, RunTrial, 'run_trial')
                for method in METHODS:
                    figures.update(run_trial(ros, client, method))
            except CallError as exc:
                raise BenchFailed(f'{exc} (logs: {suite.log_dir})', figures)
            except BenchFailed as exc:
                raise BenchFailed(f'{exc} (logs: {suite.log_dir})', figures)
    return figures


def run_trial(ros, client, method: str) -> Figures:
    """One trial's wall time and RP_all."""
    start = time.perf_counter()
    _, result = run_action(ros.node, client, RunTrial.Goal(method=method, cycles=CYCLES),
                           600.0, executor=ros.executor)
    if result.error_code != RunTrial.Result.SUCCESS:
        raise BenchFailed(f'{method} trial: {result.message}')
    return {f'trial_{method}_30x5_wall_s': (time.perf_counter() - start, 's'),
            f'trial_{method}_rp_all_mm': (result.statistics.rp_all_mm, 'mm'),
            f'trial_{method}_capture_retries': (result.capture_retries, 'count'),
            f'trial_{method}_probe_retries': (result.probe_retries, 'count')}


def run() -> Figures:
    """Trial wall times for each executor."""
    figures: Figures = {}
    for kind in benchlib.executors():
        try:
            figures.update(benchlib.suffixed(run_executor(kind), kind))
        except BenchFailed as exc:
            figures.update(benchlib.suffixed(exc.partial, kind))
            raise BenchFailed(f'{kind} executor: {exc}', figures) from exc
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
