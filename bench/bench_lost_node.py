"""A job node killed under its client: how long until the client knows (issue 38 item 1).

`cobot-calib up` (the whole default suite, as a user starts it) runs on a private domain with
the default DDS lease (20 s). For each kind of job node, one after the other, the CLI verb a
user runs is started; at its first progress line the node process is killed (SIGKILL, as a
crash), and the time from the kill to the client's exit is taken. The client must end naming
the node (the message is checked); `up` restarts the node, and the next job waits until it
answers again. BENCH_LOST_NODE_ROUNDS (default 1) rounds over the kinds.

- ``client_lost_node_seconds``: the median over every kill (goal <= 5; 22.9-23.3 s on
  12237a8, when the client learned it from the graph after the lease);
- ``client_lost_node_max_seconds``: the longest;
- ``client_lost_<node>_seconds``: each kind's (median over the rounds);
- ``lost_node_load_average_1min``: how busy the machine was.
"""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

import numpy as np

import benchlib
from benchlib import BenchFailed, Figures

READY_TIMEOUT = 300.0       # [s] for `up` to say ready (11 processes on 2 loaded cores)
PROGRESS_TIMEOUT = 240.0    # [s] for a client's first progress line
CLIENT_TIMEOUT = 120.0      # [s] a client still waiting this long after the kill: failed
# the hand-eye finds the board through the cell's active user frame: one first
USER_FRAME = ('call', 'calibrate_user_frame', '{method: rigid, point_names: [P1, P2, P3, P4, P5]}')
# (node, the verb's arguments, the client's progress line)
JOBS = (
    ('kinematic_identifier', ('identify', '--robot', 'sawyer', '--attach', '--hold', '0.02',
                              '--validation-configs', '0', '--dry-run'), '  pose '),
    ('tcp_calibrator', ('tcp',), '  touch '),
    ('hand_eye_calibrator', ('hand-eye', '--views', '12'), '  view '),
    ('camera_calibrator', ('intrinsics', '--planned', '--views', '8'), ' views, '),
    ('repeatability_trial', ('trial', '--cycles', '30'), '  cycle '),
)


class _Output:
    """The lines a process writes on one stream, read on a thread as they come."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._changed = threading.Condition()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream) -> None:
        for line in stream:
            with self._changed:
                self.lines.append(line)
                self._changed.notify_all()

    def wait_for(self, text: str, timeout: float, start: int = 0) -> bool:
        deadline = time.monotonic() + timeout
        with self._changed:
            while not any(text in line for line in self.lines[start:]):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._changed.wait(remaining)
        return True

    def text(self) -> str:
        with self._changed:
            return ''.join(self.lines)


def _cli(*args: str) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


def _node_pid(up: subprocess.Popen, node: str) -> int:
    """The pid of ``node``'s process among `up`'s children."""
    for pid in Path(f'/proc/{up.pid}/task/{up.pid}/children').read_text().split():
        cmdline = Path(f'/proc/{pid}/cmdline').read_text().split('\0')
        if f'cobot_calib_ros.nodes.{node}' in cmdline:
            return int(pid)
    raise BenchFailed(f'no {node} process under `up`')


def _kill_under_client(up, up_out: _Output, env, node: str, args, progress: str) -> float:
    """Seconds from the kill of ``node`` to its client's exit."""
    client = subprocess.Popen(_cli(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env)
    out, err = _Output(client.stdout), _Output(client.stderr)
    try:
        if not out.wait_for(progress, PROGRESS_TIMEOUT):
            raise BenchFailed(f'{" ".join(args)}: no {progress.strip()!r} line within '
                              f'{PROGRESS_TIMEOUT:.0f} s: {out.text()}{err.text()}')
        restarts = len(up_out.lines)
        os.kill(_node_pid(up, node), signal.SIGKILL)
        killed = time.monotonic()
        try:
            client.wait(timeout=CLIENT_TIMEOUT)
        except subprocess.TimeoutExpired:
            raise BenchFailed(f'{" ".join(args)}: still waiting {CLIENT_TIMEOUT:.0f} s after '
                              f'{node} was killed')
        took = time.monotonic() - killed
    finally:
        client.kill()
        client.wait()
    time.sleep(0.2)      # the reader threads take the last lines
    if f'the {node} node' not in err.text():
        raise BenchFailed(f'{" ".join(args)}: the client did not name {node}: {err.text()}')
    if not up_out.wait_for(f'{node}: restarted and answering again', READY_TIMEOUT, restarts):
        raise BenchFailed(f'{node} did not come back after the kill: {up_out.text()[-2000:]}')
    return took


def run() -> Figures:
    rounds = int(os.environ.get('BENCH_LOST_NODE_ROUNDS', '1'))
    with benchlib.private_domain() as (_domain, env):
        up = subprocess.Popen(_cli('up'), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, env=env, start_new_session=True)
        up_out = _Output(up.stdout)
        try:
            if not up_out.wait_for('ready: all ', READY_TIMEOUT):
                raise BenchFailed(f'`up` not ready in {READY_TIMEOUT:.0f} s: '
                                  f'{up_out.text()[-2000:]}')
            frame = subprocess.run(_cli(*USER_FRAME), capture_output=True, text=True,
                                   env=env, timeout=300)
            if frame.returncode != 0:
                raise BenchFailed(f'no user frame: {frame.stdout}{frame.stderr}')
            taken: dict[str, list[float]] = {node: [] for node, _, _ in JOBS}
            for _ in range(rounds):
                for node, args, progress in JOBS:
                    taken[node].append(_kill_under_client(up, up_out, env, node, args,
                                                          progress))
                    print(f'{node}: its client ended {taken[node][-1]:.2f} s after the kill '
                          f'(load {benchlib.load_average_1min():.1f})', file=sys.stderr,
                          flush=True)
        finally:
            if up.poll() is None:
                os.killpg(up.pid, signal.SIGINT)
                try:
                    up.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(up.pid, signal.SIGKILL)
                    up.wait()
    every = [t for times in taken.values() for t in times]
    figures: Figures = {'client_lost_node_seconds': (float(np.median(every)), 's'),
                        'client_lost_node_max_seconds': (float(max(every)), 's')}
    figures.update({f'client_lost_{node}_seconds': (float(np.median(times)), 's')
                    for node, times in taken.items()})
    figures['lost_node_load_average_1min'] = (benchlib.load_average_1min(), 'load')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
