"""Round trip of calibrate_user_frame with 5 explicit point pairs, beside a bare Trigger, for
each node executor side by side.

For each executor (benchlib.executors()), in namespace /<executor>: user_frame_solver (its
data_dir a throw-away directory on disk), a second solver in /<executor>/ram (data_dir on
tmpfs, where fsync costs nothing: the difference between the two is the durable write, i.e.
temporary file, fsync, rename, fsync of the directory) and bench/trigger_server.py, each its
own process on one private domain. After 20 warm-up calls each, the 500 timed calls of every
service alternate, so all see the same load on this noisy 2-core machine. Every call is
`call_async` + a `spin_once` loop (benchlib.timed_call). Goal: calibrate_user_frame_p99_ms < 2.
"""
from __future__ import annotations

import contextlib
import os
import tempfile

from cobot_calib_msgs.srv import CalibrateUserFrame
from geometry_msgs.msg import Point
import numpy as np
from std_srvs.srv import Trigger

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher

SOLVER = 'user_frame_solver'
TRIGGER = 'trigger_server'
CALLS = int(os.environ.get('BENCH_CALIBRATE_CALLS', '500'))
WARMUP = 20
NOISE = 30e-6               # [m] per axis, on the base-frame points
SEED = 20240611


def rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """R = Rz(rz) Ry(ry) Rx(rx) [rad]."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    rot_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    rot_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rot_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def point_pairs() -> tuple[list[str], np.ndarray, np.ndarray]:
    """A 0.2 x 0.15 m rectangle + its centre in the user frame, and the same in the base frame.

    Base = R user + t for a tilted, turned user frame, plus NOISE per axis (fixed seed).
    """
    names = ['corner_0', 'corner_x', 'corner_xy', 'corner_y', 'centre']
    user = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.15, 0.0], [0.0, 0.15, 0.0],
                     [0.1, 0.075, 0.0]])
    R = rotation(np.radians(1.5), np.radians(-0.8), np.radians(32.0))
    t = np.array([0.55, -0.18, 0.042])
    base = user @ R.T + t + np.random.default_rng(SEED).normal(0.0, NOISE, user.shape)
    return names, user, base


def calibrate_request() -> CalibrateUserFrame.Request:
    """The rigid-fit request with the explicit point pairs (frames: the node's defaults)."""
    names, user, base = point_pairs()
    return CalibrateUserFrame.Request(
        method='', point_names=names, fit_surface=False, base_frame='', user_frame='',
        points_user=[Point(x=x, y=y, z=z) for x, y, z in user.tolist()],
        points_base=[Point(x=x, y=y, z=z) for x, y, z in base.tolist()])


def trigger_error(response) -> str | None:
    return None if response.success else f'trigger answered success=False: {response.message}'


def calibrate_error(response) -> str | None:
    if response.error_code == CalibrateUserFrame.Response.SUCCESS:
        return None
    return f'calibrate_user_frame refused (code {response.error_code}): {response.message}'


class Target:
    """One service under test: its client, request, answer check and measured round trips."""

    def __init__(self, name: str, client, request, error) -> None:
        self.name, self.client, self.request, self.error = name, client, request, error
        self.times: list[float] = []

    def call(self, ros: Ros) -> float:
        """One checked round trip [s]."""
        seconds, response = benchlib.timed_call(ros, self.client, self.request)
        why = self.error(response)
        if why:
            raise BenchFailed(why)
        return seconds


def measure_interleaved(ros: Ros, targets: list[Target]) -> Figures:
    """WARMUP untimed calls of each, then CALLS timed calls of each, alternating."""
    for _ in range(WARMUP):
        for target in targets:
            target.call(ros)
    for _ in range(CALLS):
        for target in targets:
            target.times.append(target.call(ros))
    figures: Figures = {}
    for target in targets:
        figures.update(benchlib.percentiles_ms(target.name, target.times))
    return figures


def specs(kind: str, disk_dir: str, ram_dir: str) -> list[launcher.NodeSpec]:
    """Trigger server, solver on disk and solver on tmpfs, in namespace /<kind>."""
    solver = launcher.suite_specs(paths.DEFAULT_CELL, (SOLVER,))[0]
    return [benchlib.ScriptSpec(TRIGGER, namespace=kind),
            launcher.NodeSpec(SOLVER, {**solver.params, 'data_dir': disk_dir}, namespace=kind),
            launcher.NodeSpec(SOLVER, {**solver.params, 'data_dir': ram_dir},
                              namespace=f'{kind}/ram')]


def targets(ros: Ros, suite: launcher.Suite, kind: str) -> list[Target]:
    """The three services of one executor's processes, once they are ready."""
    request = calibrate_request()
    found = [Target(f'trigger_roundtrip_{kind}',
                    ros.node.create_client(Trigger, f'/{kind}/bench_trigger'),
                    Trigger.Request(), trigger_error),
             Target(f'calibrate_user_frame_{kind}',
                    ros.node.create_client(CalibrateUserFrame, f'/{kind}/calibrate_user_frame'),
                    request, calibrate_error),
             Target(f'calibrate_user_frame_tmpfs_{kind}',
                    ros.node.create_client(CalibrateUserFrame,
                                           f'/{kind}/ram/calibrate_user_frame'),
                    request, calibrate_error)]
    for target in found:
        benchlib.wait_for_service(ros, suite, f'{kind} {target.name}', target.client)
    return found


def renamed(figures: Figures, kinds: list[str]) -> Figures:
    """`<service>_<kind>_p99_ms` -> `<service>_p99_ms_<kind>`, and calibrate minus trigger."""
    out: Figures = {}
    for name, value in figures.items():
        kind = next(k for k in kinds if f'_{k}_p' in name)
        service, stat = name.split(f'_{kind}_')
        out[f'{service}_{stat}_{kind}'] = value
    for kind in kinds:
        out[f'calibrate_user_frame_minus_trigger_p50_ms_{kind}'] = (
            out[f'calibrate_user_frame_p50_ms_{kind}'][0]
            - out[f'trigger_roundtrip_p50_ms_{kind}'][0], 'ms')
    return out


def run() -> Figures:
    """calibrate_user_frame and Trigger round-trip percentiles, per executor, interleaved."""
    kinds = benchlib.executors()
    with benchlib.private_domain() as (domain, env), contextlib.ExitStack() as stack:
        suites = {}
        for kind in kinds:
            disk = stack.enter_context(tempfile.TemporaryDirectory(
                prefix=f'cobot_bench_{kind}_', dir=env['COBOT_CALIB_DATA']))
            ram = stack.enter_context(tempfile.TemporaryDirectory(
                prefix=f'cobot_bench_{kind}_', dir='/dev/shm'))
            suites[kind] = stack.enter_context(benchlib.running_suite(
                f'calibrate_{kind}', specs(kind, disk, ram), benchlib.executor_env(env, kind)))
        ros = stack.enter_context(benchlib.ros_node('bench_calibrate_user_frame', domain))
        load_start = benchlib.load_average_1min()
        everything = [t for kind in kinds for t in targets(ros, suites[kind], kind)]
        figures = renamed(measure_interleaved(ros, everything), kinds)
    figures['calibrate_load_average_1min'] = (
        0.5 * (load_start + benchlib.load_average_1min()), 'load')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
