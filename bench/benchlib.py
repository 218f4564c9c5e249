"""Shared helpers of the benches: a private ROS domain, node processes, timed calls, figures.

Every bench module `bench/bench_*.py` has `run() -> dict[str, tuple[float, str]]` (figure name
-> (value, unit)); `bench/run_all.py` runs them all. Waits use `call_async` and a `spin_once`
loop (`cobot_calib_ros.ros.calls.spin_until`), never `spin_until_future_complete`.

Figure names end with their unit (`_ms`, `_hz`, `_percent`, ...; counts say what they count),
then, for figures measured once per node executor, `_single` or `_events`. The executors are
those of $BENCH_EXECUTORS (default `single,events`); a node process gets its executor through
$COBOT_CALIB_EXECUTOR (cobot_calib_ros.ros.spin).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
import os
from pathlib import Path
import sys
import tempfile
import time
from typing import Callable, Iterator

import cobot_calib_ros  # noqa: F401  (before numpy: its one BLAS thread, as the nodes and CLI)
import domain_coordinator
import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.session import session

BENCH_DIR = Path(__file__).resolve().parent
REPO_ROOT = BENCH_DIR.parent
STARTUP_TIMEOUT = 120.0  # [s] for a node process to offer its service (cold imports on a
                         # loaded 2-core machine took over 30 s)

Figures = dict[str, tuple[float, str]]


class BenchFailed(RuntimeError):
    """A bench that could not finish; `partial` holds the figures it did measure."""

    def __init__(self, reason: str, partial: Figures | None = None) -> None:
        super().__init__(reason)
        self.partial = dict(partial or {})


@dataclass
class Ros:
    """The bench process's own rclpy context, node and executor on the private domain."""

    node: Node
    executor: SingleThreadedExecutor

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Spin until done() or the timeout [s]; returns done()."""
        return spin_until(self.node, done, timeout, self.executor)

    def spin_for(self, seconds: float) -> None:
        """Process callbacks for `seconds`."""
        self.spin_until(lambda: False, seconds)


class ScriptSpec(launcher.NodeSpec):
    """A node run from a script in bench/ (not a cobot_calib_ros node) by launcher.Suite."""

    def command(self) -> list[str]:
        cmd = [sys.executable, str(BENCH_DIR / f'{self.name}.py'), '--ros-args']
        for key, value in self.params.items():
            cmd += ['-p', f'{key}:={value}']
        if self.namespace:
            cmd += ['-r', f'__ns:=/{self.namespace.strip("/")}']
        return cmd


def executors() -> list[str]:
    """The node executors to measure: $BENCH_EXECUTORS (comma-separated), default all."""
    kinds = [k.strip() for k in os.environ.get('BENCH_EXECUTORS', '').split(',') if k.strip()]
    unknown = sorted(set(kinds) - set(spin.EXECUTORS))
    if unknown:
        raise ValueError(f'BENCH_EXECUTORS: unknown {unknown}; use {", ".join(spin.EXECUTORS)}')
    return kinds or sorted(spin.EXECUTORS, reverse=True)   # single first, then events


def executor_env(env: dict[str, str], kind: str) -> dict[str, str]:
    """`env` with the node executor `kind` chosen for the processes started with it."""
    return dict(env, **{spin.EXECUTOR_ENV: kind})


def suffixed(figures: Figures, suffix: str) -> Figures:
    """Every figure name with `_<suffix>` appended."""
    return {f'{name}_{suffix}': value for name, value in figures.items()}


def load_average_1min() -> float:
    """The machine's 1-minute load average (2 cores here: above 2, processes wait for CPU)."""
    return os.getloadavg()[0]


@contextmanager
def private_domain() -> Iterator[tuple[int, dict[str, str]]]:
    """A free ROS_DOMAIN_ID (reserved while in use) and the environment for child processes.

    Discovery stays on this machine; results a node may store go to a throw-away directory.
    """
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # read by rmw at init
    with domain_coordinator.domain_id() as domain, \
            tempfile.TemporaryDirectory(prefix='cobot_bench_') as scratch:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', COBOT_CALIB_DATA=scratch,
                   PYTHONUNBUFFERED='1')
        yield domain, env


@contextmanager
def ros_node(name: str, domain: int) -> Iterator[Ros]:
    """An rclpy context, node and single-threaded executor of the bench process
    (ros.session on ``domain``)."""
    with session(name, domain_id=domain) as (node, executor):
        yield Ros(node, executor)


@contextmanager
def running_suite(name: str, specs: list[launcher.NodeSpec],
                  env: dict[str, str]) -> Iterator[launcher.Suite]:
    """Node processes started with launcher.Suite; always stopped (SIGINT..SIGKILL) on exit."""
    suite = launcher.Suite(launcher.default_log_dir().with_name(
        f'cobot_bench_{name}_{time.strftime("%Y%m%dT%H%M%S")}_{os.getpid()}'))
    try:
        suite.start(specs, env=env)
        yield suite
    finally:
        suite.stop()


def wait_for_service(ros: Ros, suite: launcher.Suite, node_name: str, client,
                     timeout: float = STARTUP_TIMEOUT) -> None:
    """Wait until `client`'s service (of `node_name`) is ready; BenchFailed if a node exits."""
    ros.spin_until(lambda: client.service_is_ready() or bool(suite.failed()), timeout)
    if client.service_is_ready() and not suite.failed():
        return
    if not suite.failed():
        raise BenchFailed(f'{node_name} did not start: service {client.srv_name} not ready '
                          f'within {timeout:.0f} s (log: {suite.log_dir})')
    raise BenchFailed('; '.join(exit_report(suite, name, code)
                                for name, code in suite.failed().items()))


def exit_report(suite: launcher.Suite, name: str, code: int) -> str:
    """`<name> did not start: exited with code N: <last log lines>` for a failure message."""
    tail = suite.log_tail(name, 3).strip().replace('\n', ' | ')
    return (f'{name} did not start: exited with code {code}' + (f': {tail}' if tail else '')
            + f' (log: {suite.log_dir / (name + ".log")})')


def timed_call(ros: Ros, client, request, timeout: float = 10.0):
    """One service round trip: (seconds from call_async to the response, response)."""
    start = time.perf_counter()
    future = client.call_async(request)
    if not ros.spin_until(future.done, timeout):
        client.remove_pending_request(future)
        raise BenchFailed(f'service {client.srv_name} did not answer within {timeout:.0f} s')
    return time.perf_counter() - start, future.result()


def percentiles_ms(name: str, seconds: list[float]) -> Figures:
    """`<name>_p50_ms` and `<name>_p99_ms` of durations given in seconds."""
    p50, p99 = np.percentile(np.asarray(seconds) * 1e3, [50, 99])
    return {f'{name}_p50_ms': (float(p50), 'ms'), f'{name}_p99_ms': (float(p99), 'ms')}


def format_figure(name: str, value: float, unit: str) -> str:
    """One result line: `name: value unit`."""
    if isinstance(value, int) or float(value).is_integer() and unit == 'count':
        text = f'{int(value)}'
    elif abs(value) >= 100:
        text = f'{value:.1f}'
    else:
        text = f'{value:.3f}'
    return f'{name}: {text} {unit}'.rstrip()


def main(run: Callable[[], Figures]) -> int:
    """Run one bench module on its own and print its figures."""
    try:
        figures = run()
    except BenchFailed as exc:
        for name, (value, unit) in exc.partial.items():
            print(format_figure(name, value, unit))
        print(f'{Path(sys.argv[0]).stem.removeprefix("bench_")}: FAILED ({exc})')
        return 1
    for name, (value, unit) in figures.items():
        print(format_figure(name, value, unit))
    return 0


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] a process has used (all its threads), from /proc."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return float('nan')
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
