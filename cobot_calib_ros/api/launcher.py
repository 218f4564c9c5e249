"""Start the node suite as separate processes and stop every one of them cleanly.

`launch` / `launch_ros` are not on PyPI; this is the project's own minimal launcher. Each node
runs as `python -m cobot_calib_ros.nodes.<name> --ros-args --params-file config/<name>.yaml`,
which is what `ros2 run` does with the installed executable on a full ROS install. A node that
exits can be started again with the same command (`restart`, as launch's ``respawn``; its log
goes on in the same file), and `AnswerCheck` tells whether a node answers yet.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from cobot_calib_ros import paths
from cobot_calib_ros.nodes import DRIVER_NODES, NODES
from cobot_calib_ros.api.dds_profile import large_data_env
from cobot_calib_ros.api.fastdds_shm import remove_stale_segments
from cobot_calib_ros.ros.action_client import ASK_AGAIN
from cobot_calib_ros.ros.spin import LAUNCHER_PID_ENV, STOP_BOUND

SUITE = tuple(n for n in NODES if n not in DRIVER_NODES)   # the suite, in launch order
ROBOT_INTERFACES = ('move_to', 'driver')    # mock_robot's own move_to, or through robot_adapter
# [s] from a stop's SIGINT to the SIGTERM: a node ends by itself within spin.STOP_BOUND
# (its teardown cut short by its watchdog at worst), so a SIGTERM means it did not
STOP_WAIT = STOP_BOUND + 1.0


@dataclass
class NodeSpec:
    name: str
    params: dict[str, str] = field(default_factory=dict)
    namespace: str = ''

    @property
    def key(self) -> str:
        """'name', or 'namespace.name': the node's key in Suite.processes and its log's name."""
        return f'{self.namespace.strip("/")}.{self.name}' if self.namespace else self.name

    @property
    def full_name(self) -> str:
        """'/namespace/name' as the ROS graph shows the node."""
        ns = self.namespace.strip('/')
        return f'/{ns}/{self.name}' if ns else f'/{self.name}'

    def command(self) -> list[str]:
        """The node's command line. Its console output is its log (Suite.log_path), so rcl's own
        log file, the same lines again as python_<pid>.log in the ROS log root, is not written
        (--disable-external-lib-logs; ros.session.FILE_LOG_ENV=1 keeps it)."""
        from cobot_calib_ros.ros.session import no_log_file_args
        cmd = [sys.executable, '-m', f'cobot_calib_ros.nodes.{self.name}', '--ros-args',
               *no_log_file_args()]
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
    specs: dict[str, NodeSpec] = field(default_factory=dict)
    # own_group: each node in a process group of its own, so a Ctrl-C at the terminal reaches
    # only the launcher, which then stops every node with exactly one SIGINT (`cobot-calib up`)
    own_group: bool = False
    _env: dict[str, str] | None = None

    def start(self, specs: list[NodeSpec], env: dict[str, str] | None = None) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        remove_stale_segments()     # of suites killed before: 16 MB of memory each
        prepare_stores(specs, env)
        self._env = env
        for spec in specs:
            self.specs[spec.key] = spec
            self._launch(spec, 'wb')

    def restart(self, key: str) -> None:
        """Start node ``key`` again (it has exited); its log goes on in the same file."""
        self._launch(self.specs[key], 'ab')

    def _launch(self, spec: NodeSpec, mode: str) -> None:
        # the node asks for a SIGTERM when this process dies (spin.die_with_launcher): no
        # preexec_fn, which can deadlock the child of a process with DDS threads before its
        # exec, and Popen waits for that exec (a restart in `up` once hung so)
        env = {**large_data_env(self._env), LAUNCHER_PID_ENV: str(os.getpid())}
        with open(self.log_path(spec.key), mode) as log:
            self.processes[spec.key] = subprocess.Popen(
                spec.command(), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                env=env, process_group=0 if self.own_group else None)

    def log_path(self, key: str) -> Path:
        return self.log_dir / f'{key.replace("/", ".")}.log'

    def failed(self) -> dict[str, int]:
        """Nodes that have exited, with their exit codes."""
        return {n: p.returncode for n, p in self.processes.items() if p.poll() is not None}

    def log_tail(self, name: str, lines: int = 20) -> str:
        path = self.log_path(name)
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])

    def stop(self, timeout: float = STOP_WAIT) -> dict[str, int]:
        """SIGINT every node, then SIGTERM ``timeout`` s later, then SIGKILL 2 s after that;
        returns the exit codes."""
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


def prepare_stores(specs: list[NodeSpec], env: dict[str, str] | None = None) -> None:
    """The SQLite databases the nodes of ``specs`` will store in (each one's data_dir
    parameter, else ``env``'s data dir), brought to the newest migration before they start
    (store.database.prepare). A server database is left to the nodes (an unreachable host
    would hold every node back here), as is whatever cannot be prepared: they say why."""
    from cobot_calib_ros.store.database import DB_ENV, prepare
    from cobot_calib_ros.store.repository import database_url
    environ = os.environ if env is None else env
    for given in {spec.params.get('data_dir', '') for spec in specs}:
        try:
            url = database_url(paths.data_dir(given, environ), environ.get(DB_ENV) or None)
            if url.startswith('sqlite'):
                prepare(url)
        except Exception:  # noqa: BLE001 - the node's own open says what is wrong, and how
            pass


class AnswerCheck:
    """Whether a node (full name, '/mock_robot') has answered a call to its parameter service;
    ``answered()`` never blocks (spin the node between looks). An answer means the node process
    is up and spinning, so every service and action server it offers is there. A node killed
    and started again stays in the graph until DDS's lease ends: a call that went to the dead
    one never answers, so an unanswered call is sent again every ASK_AGAIN s."""

    def __init__(self, node, full_name: str) -> None:
        from rcl_interfaces.srv import ListParameters
        self._node, self._request = node, ListParameters.Request(depth=1)
        self._client = node.create_client(ListParameters, f'{full_name}/list_parameters')
        self._call, self._asked = None, 0.0

    def answered(self) -> bool:
        if self._call is not None and self._call.done():
            return True
        now = time.monotonic()
        if now - self._asked >= ASK_AGAIN and self._client.service_is_ready():
            if self._call is not None:
                self._client.remove_pending_request(self._call)
            self._call, self._asked = self._client.call_async(self._request), now
        return False

    def close(self) -> None:
        self._node.destroy_client(self._client)


def suite_specs(cell: str, nodes: tuple[str, ...] = SUITE,
                overrides: dict[str, dict[str, str]] | None = None,
                robot_interface: str = 'move_to') -> list[NodeSpec]:
    """The node suite for one cell file; every node gets `cell_file`. ``robot_interface``
    ``driver``: mock_robot offers only joint_states and FollowJointTrajectory, as a ros2_control
    arm, and robot_adapter (after it) serves move_to over them with the ``mock`` preset."""
    overrides = dict(overrides or {})
    if robot_interface == 'driver' and 'mock_robot' in nodes:
        overrides['mock_robot'] = {'robot_interface': 'driver', **overrides.get('mock_robot', {})}
        at = nodes.index('mock_robot') + 1
        nodes = (*nodes[:at], *DRIVER_NODES, *nodes[at:])
    elif robot_interface not in ROBOT_INTERFACES:
        raise ValueError(f'robot_interface {robot_interface!r}: use one of {ROBOT_INTERFACES}')
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
