"""Round trip of calibrate_user_frame with 5 explicit point pairs, beside a bare Trigger.

user_frame_solver and bench/trigger_server.py run as separate processes on a private domain.
After 20 warm-up calls each, the 500 timed calls of each service alternate, so both see the same
load on this noisy 2-core machine and their figures can be compared side by side. Every call is
`call_async` + a `spin_once` loop (benchlib.timed_call). The solver stores each calibration; its
data_dir is a throw-away directory on disk. A second solver (namespace /ram) keeps its data_dir
on tmpfs, where fsync costs nothing: the difference between the two is the durable write
(temporary file, fsync, rename, fsync of the directory).
"""
from __future__ import annotations

import tempfile

from cobot_calib_msgs.srv import CalibrateUserFrame
from geometry_msgs.msg import Point
import numpy as np
from std_srvs.srv import Trigger

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros.api import launcher

SOLVER = 'user_frame_solver'
TRIGGER = 'trigger_server'
CALLS = 500
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


def start_solver(ros: Ros, suite: launcher.Suite, client) -> str | None:
    """Wait for the solver; None when ready, else why it did not start."""
    try:
        benchlib.wait_for_service(ros, suite, SOLVER, client)
    except BenchFailed as exc:
        return str(exc)
    return None


def run() -> Figures:
    """calibrate_user_frame and Trigger round-trip percentiles."""
    with benchlib.private_domain() as (domain, env), \
            tempfile.TemporaryDirectory(prefix='cobot_bench_', dir='/dev/shm') as ram_dir:
        solver_specs = launcher.suite_specs('sawyer_close', (SOLVER,), overrides={
            SOLVER: {'data_dir': env['COBOT_CALIB_DATA']}})
        solver_specs.append(launcher.NodeSpec(
            SOLVER, {**solver_specs[0].params, 'data_dir': ram_dir}, namespace='ram'))
        with benchlib.running_suite('trigger', [benchlib.ScriptSpec(TRIGGER)], env) as trig, \
                benchlib.running_suite(SOLVER, solver_specs, env) as solver, \
                benchlib.ros_node('bench_calibrate_user_frame', domain) as ros:
            trigger = ros.node.create_client(Trigger, 'bench_trigger')
            calibrate = ros.node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
            calibrate_ram = ros.node.create_client(CalibrateUserFrame,
                                                   '/ram/calibrate_user_frame')
            benchlib.wait_for_service(ros, trig, TRIGGER, trigger)
            solver_failed = (start_solver(ros, solver, calibrate)
                             or start_solver(ros, solver, calibrate_ram))
            targets = [Target('trigger_roundtrip', trigger, Trigger.Request(), trigger_error)]
            if solver_failed is None:
                targets.append(Target('calibrate_user_frame_roundtrip', calibrate,
                                      calibrate_request(), calibrate_error))
                targets.append(Target('calibrate_user_frame_tmpfs_roundtrip', calibrate_ram,
                                      calibrate_request(), calibrate_error))
            figures = measure_interleaved(ros, targets)
    if solver_failed is not None:
        raise BenchFailed(solver_failed, figures)
    figures['calibrate_user_frame_minus_trigger_p50'] = (
        figures['calibrate_user_frame_roundtrip_p50'][0] - figures['trigger_roundtrip_p50'][0],
        'ms')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
