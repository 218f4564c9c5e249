"""Offline identification of 10,000 tracker points (issue 28 item 8), the path users take.

`cobot-calib identify --measurement points --source FILE --urdf ...` (api identify_source: its
defaults, 5-fold held out, soft-L1 loss, the full error model of a URDF) on a measurement file
of ROWS rows written from the truth of the mock ur10e_close cell: configurations drawn within
80 % of the joint limits, the laser tracker measuring the true coupling centre (with its
noise), the joints as the encoders read them. Pure computation, no ROS; seeded.

- ``identify_points_10000_rows_seconds``: wall time of identify_source (reading the file
  included; writing it not); ``_cpu_seconds`` the CPU time it took (below the wall time: the
  machine was busy);
- ``identify_points_10000_rows_held_out_{nominal,calibrated}_rmse_mm``: what it found.
"""
from __future__ import annotations

import benchlib  # first: cobot_calib_ros before numpy (one BLAS thread), run alone too
import csv
from pathlib import Path
import tempfile
import time

import numpy as np
import yaml

from benchlib import Figures
from cobot_calib_ros.api.identification import identify_source
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

CELL = 'ur10e_close'
ROWS = 10_000
SEED = 11
MARKER_COLUMNS = ['coupling_x', 'coupling_y', 'coupling_z']


def write_points_file(folder: Path, rows: int = ROWS, seed: int = SEED) -> tuple[Path, Path]:
    """(CSV with its sidecar, the arm's URDF) of ``rows`` tracker points of the mock cell."""
    sim = load_simulation(cell_file(CELL))
    robot = SimRobot(sim)
    model = robot.model
    rng = np.random.default_rng(seed)
    q = rng.uniform(model.lower * 0.8, model.upper * 0.8, (rows, len(model.joint_names)))
    tracker = sim.spheres.tracker
    measured = np.array([tracker.measure(p, rng)
                         for p in kinematics.fk(robot.coupling, q)[:, :3, 3]])
    q_read = q + rng.normal(0.0, sim.noise.encoder_sigma, q.shape)
    csv_path = folder / 'tracker_points.csv'
    with csv_path.open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(list(model.joint_names) + MARKER_COLUMNS)
        writer.writerows(np.hstack([q_read, measured]).tolist())
    sidecar = {'measurement': 'points', 'units': {'length': 'm', 'angle': 'rad'},
               'joints': list(model.joint_names),
               'frames': {'measured_in': 'tracker', 'base': sim.cell.urdf_robot.base_link,
                          'tip': sim.cell.urdf_robot.tip_link},
               'markers': {'coupling': MARKER_COLUMNS},
               'ball': sim.cell.spheres.T_flange_coupling[:3, 3].tolist()}
    csv_path.with_suffix('.yaml').write_text(yaml.safe_dump(sidecar, sort_keys=False))
    urdf = Path(cell_file(CELL)).parent / sim.cell.urdf_robot.urdf_file
    return csv_path, urdf


def run(rows: int = ROWS) -> Figures:
    with tempfile.TemporaryDirectory(prefix='cobot_bench_points_') as scratch:
        source, urdf = write_points_file(Path(scratch), rows)
        start, cpu = time.perf_counter(), time.process_time()
        report = identify_source(source, measurement='points', urdf=str(urdf))
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    name = f'identify_points_{rows}_rows'
    held = report['held_out']
    return {f'{name}_seconds': (seconds, 's'),
            f'{name}_cpu_seconds': (cpu, 's'),
            f'{name}_held_out_nominal_rmse_mm': (held['nominal']['rmse_mm'], 'mm'),
            f'{name}_held_out_calibrated_rmse_mm': (held['calibrated']['rmse_mm'], 'mm'),
            f'{name}_parameters_kept': (float(report['parameters_kept']), 'parameters'),
            f'{name}_load_1min': (benchlib.load_average_1min(), 'load')}


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
