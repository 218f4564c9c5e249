"""Start the node suite as separate processes and stop every one of them cleanly.

`launch` / `launch_ros` are not on PyPI; this is the project's own minimal launcher. Each node
runs as `python -m cobot_calib_ros.nodes.<name> --ros-args --params-file config/<name>.yaml`,
which is what `ros2 run` does with the installed executable on a full ROS install.
"""
from __future__ import annotations

import contextlib
import ctypes
from dataclasses import dataclass, field
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from cobot_calib_ros import paths
from cobot_calib_ros.nodes import NODES

SUITE = NODES                 # the whole suite, in launch order
PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """Child-side: get SIGTERM if the launcher dies, so no orphan outlives it (Linux)."""
    try:
        ctypes.CDLL('libc.so.6').prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass


@dataclass
class NodeSpec:
    name: str
    params: dict[str, str] = field(default_factory=dict)
    namespace: str = ''

    def command(self) -> list[str]:
        cmd = [sys.executable, '-m', f'cobot_calib_ros.nodes.{self.name}', '--ros-args']
        params_file = paths.config_dir() / f'{self.name}.yaml'
        if params_file.exists():
            cmd += ['--params-file', str(params_file)]
        for key, value in self.params.items():
            cmd += ['-p', f'{key}:={value}']
        if self.namespace:
            cmd += ['-r', f'__ns:=/{self.namespace.strip("/")}']
        return cmd


@dataclass
class Suite:
    """A running set of node processes with their logs."""

    log_dir: Path
    processes: dict[str, subprocess.Popen] = field(default_factory=dict)

    def start(self, specs: list[NodeSpec], env: dict[str, str] | None = None) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        for spec in specs:
            key = f'{spec.namespace.strip("/")}.{spec.name}' if spec.namespace else spec.name
            log = open(self.log_dir / f'{key.replace("/", ".")}.log', 'wb')
            self.processes[key] = subprocess.Popen(
                spec.command(), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                env=env, preexec_fn=_die_with_parent)
            log.close()

    def failed(self) -> dict[str, int]:
        """Nodes that have exited, with their exit codes."""
        return {n: p.returncode for n, p in self.processes.items() if p.poll() is not None}

    def log_tail(self, name: str, lines: int = 20) -> str:
        path = self.log_dir / f'{name}.log'
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])

    def stop(self, timeout: float = 5.0) -> dict[str, int]:
        """SIGINT every node, then SIGTERM, then SIGKILL; returns the exit codes."""
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            alive = [p for p in self.processes.values() if p.poll() is None]
            for p in alive:
                p.send_signal(sig)
            deadline = time.monotonic() + wait
            for p in alive:
                try:
                    p.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
        return {n: p.returncode for n, p in self.processes.items()}


def suite_specs(cell: str, nodes: tuple[str, ...] = SUITE,
                overrides: dict[str, dict[str, str]] | None = None) -> list[NodeSpec]:
    """The node suite for one cell file; every node gets `cell_file`."""
    overrides = overrides or {}
    cell_path = str(paths.cell_file(cell))
    return [NodeSpec(n, {'cell_file': cell_path, **overrides.get(n, {})}) for n in nodes]


def default_log_dir() -> Path:
    stamp = time.strftime('%Y%m%dT%H%M%S')
    root = Path(os.environ.get('ROS_LOG_DIR', Path.home() / '.ros' / 'log'))
    return root / f'cobot_calib_{stamp}_{os.getpid()}'


@contextlib.contextmanager
def private_suite(cell: str, overrides: dict[str, dict[str, str]] | None = None,
                  say=print):
    """The node suite on a free ROS_DOMAIN_ID of its own (set in os.environ while it runs)."""
    import domain_coordinator
    with domain_coordinator.domain_id() as domain:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        suite = Suite(default_log_dir())
        suite.start(suite_specs(cell, overrides=overrides))
        say(f'node suite on ROS_DOMAIN_ID={domain}, logs in {suite.log_dir}')
        try:
            yield suite
        finally:
            suite.stop()
