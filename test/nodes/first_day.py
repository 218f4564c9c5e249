"""Issue 36 must-show 3 (run by test_first_day_*.py): a new cell's first day with the README's
defaults, on each mock cell's whole node suite (`cobot-calib up`'s nodes as processes, own
domain, temporary data_dir): `identify --attach --planned`, `tcp`, `calibrate_user_frame` rigid
P1-P5, `intrinsics --planned`, `hand-eye`, `move --frame user`; every step succeeds (iiwa7_close
has no wrist camera: its intrinsics and hand-eye are refused before anything moves, saying so),
and the tool `move` sends over the layout's centre lands there: the mock's TRUE tool tip against
the target in the frame the TRUE marker tops define.

Nothing but the mock's defaults is changed (the verbs' and the nodes' own defaults), except
that the mock moves four times faster than its cell's time_scale (TIME_SCALE). Slow by
nature: the planned identification dominates (the candidate poses' IK and 50 planned poses,
then two 125-pose validation collections); each step's wall time is printed.
"""
import json
import os
import subprocess
import time

import domain_coordinator
import numpy as np

from cobot_calib_ros.api import launcher
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from rosutil import cli_command, STOP_TIMEOUT

# a placement through the calibrated cell (bench/bench_placement.py: 0.03-0.06 mm max at the
# markers); the nominal cell's is 0.1-0.25 mm
MAX_PLACEMENT_MM = 0.15
HEIGHT = 0.05       # [m] of the move's target above the layout's centre
# the mock's motions at a quarter of the cells' time_scale (0.02): ~2,200 s of simulated motion
# in the three first days took ~44 s of the tests' time (the calibrations see the same poses)
TIME_SCALE = 0.005


def _run(env, *args, timeout=1200) -> tuple[subprocess.CompletedProcess, float]:
    start = time.monotonic()
    out = subprocess.run(cli_command(*args), env=env, capture_output=True, text=True,
                         timeout=timeout)
    return out, time.monotonic() - start


def run_the_first_day(cell: str, tmp_path) -> None:
    """The first day on ``cell``'s suite, every step asserted (the module doc); one test file per
    cell (test_first_day_<robot>.py), so that pytest-xdist's loadfile gives the three ~2 min
    runs to whichever worker is free."""
    sim = load_simulation(cell_file(cell))
    camera = sim.cell.camera is not None and sim.cell.landmarks is not None
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), COBOT_CALIB_DATA=str(tmp_path),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        suite = launcher.Suite(tmp_path / 'logs')
        suite.start(launcher.suite_specs(cell, overrides={
            'mock_robot': {'time_scale': str(TIME_SCALE)}}), env=env)
        try:
            centre = sim.cell.nominal_points_user().mean(axis=0)
            target = [float(centre[0]), float(centre[1]), float(centre[2] + HEIGHT)]
            steps = [
                ('identify', '--attach', '--planned'),
                ('tcp',),
                ('call', 'calibrate_user_frame',
                 '{method: rigid, point_names: [P1, P2, P3, P4, P5]}'),
                ('intrinsics', '--planned'),
                ('hand-eye',),
                ('move', '--frame', 'user', '--xyz', *map(str, target),
                 '--rpy', '3.1416', '0', '0', '--json')]
            seconds = {}
            for args in steps:
                out, seconds[args[0]] = _run(env, *args)
                print(f'{cell}: {" ".join(args[:2])}: exit {out.returncode}, '
                      f'{seconds[args[0]]:.1f} s')
                logs = '\n'.join(f'--- {n}\n{suite.log_tail(n)}' for n in suite.processes)
                text = f'{out.stdout[-3000:]}\n{out.stderr[-3000:]}'
                if args[0] in ('intrinsics', 'hand-eye') and not camera:
                    assert out.returncode == 1 and 'has no wrist camera' in out.stderr, text
                    continue
                assert out.returncode == 0, f'{args}: {text}\n{logs}'
                if args[0] == 'call':
                    assert 'error_code: 0' in out.stdout, text
        finally:
            codes = suite.stop(STOP_TIMEOUT)
    print(f'{cell}: first day {sum(seconds.values()):.0f} s '
          f'({", ".join(f"{k} {v:.0f} s" for k, v in seconds.items())})')
    moved = json.loads(out.stdout.strip().splitlines()[-1])
    assert moved['moved'] and moved['kinematics'] != 'nominal'
    # the truth: where the true arm and tool put the tip at the joints reached, against the
    # target in the frame of the true marker tops
    arm = SimRobot(sim)
    tip = kinematics.fk(arm.true, np.array(moved['reached']))[:3, 3]
    T_ref = user_frame.calibrate('rigid', sim.cell.nominal_points_user(),
                                 sim.world.true_points_base(), max_rms_error=None).T_base_user
    error_mm = np.linalg.norm(tip - frames.apply(T_ref, target)) * 1e3
    print(f'{cell}: the true tool tip {error_mm:.3f} mm from the target')
    assert error_mm < MAX_PLACEMENT_MM
    assert all(c == 0 for c in codes.values()), f'nodes did not exit cleanly: {codes}'
