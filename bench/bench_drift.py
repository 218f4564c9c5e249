"""Drift alarms on the simulated Sawyer cell (issue 19 must-show 2), in-process (no ROS):
user-frame calibrations (rigid, 5 touched markers, new operator noise each) stored in a
SQLite database and compared one after the other (store.history, core.drift defaults: 3
standard errors AND 0.2 mm / 1 mrad).

- ``drift_false_alarms`` [count]: alarms over REPEATS repeat calibrations, nothing moved;
- ``drift_detected_after_calibrations`` [count]: calibrations after the table moved 0.3 mm
  until the WARN, worst over MOVES moves in random directions (1: the first one warns);
- ``drift_missed_moves`` [count]: moves of 0.3 mm with no WARN at the first calibration;
- ``drift_repeat_change_p95_mm`` [mm]: how far repeats move the frame (noise).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import benchlib
from benchlib import Figures

from cobot_calib_ros import store
from cobot_calib_ros.core.drift import OK
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import calibrate_user_frame, moved_table
from cobot_calib_ros.store.history import user_frame_steps
from cobot_calib_ros.store.records import UserFrameRecord

REPEATS = 50
MOVES = 30
MOVE_M = 0.3e-3


def _store(repo, sim, seed: int, stamp: int) -> None:
    run = calibrate_user_frame(sim, seed)
    record = UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                      ('base', 'user'), stamp)
    record.id = f'uf-{stamp:05d}'
    repo.user_frames.save_and_activate(record)


def run() -> Figures:
    sim = load_simulation(cell_file())
    rng = np.random.default_rng(19)
    with tempfile.TemporaryDirectory(prefix='bench_drift_') as tmp:
        url = f'sqlite:///{Path(tmp) / "drift.sqlite"}'
        repo = store.open(tmp, url, 'repeats')
        for k in range(REPEATS + 1):
            _store(repo, sim, 1000 + k, k)
        repeats = user_frame_steps(repo.user_frames.history())[1:]
        false_alarms = sum(1 for s in repeats if s.change.level != OK)
        after, missed = [], 0
        for m in range(MOVES):
            moves = store.open(tmp, url, f'move_{m}')
            _store(moves, sim, 2000 + m, 0)
            direction = rng.normal(size=3)
            shifted = moved_table(sim, MOVE_M * direction / np.linalg.norm(direction))
            for k in range(1, 4):          # calibrations after the move, until the WARN
                _store(moves, shifted, 3000 + 10 * m + k, k)
                if user_frame_steps(moves.user_frames.history())[-1].change.level != OK:
                    after.append(k)
                    break
            else:
                after.append(np.inf)
            missed += after[-1] != 1
    return {'drift_false_alarms': (false_alarms, 'count'),
            'drift_repeats': (len(repeats), 'count'),
            'drift_detected_after_calibrations': (float(max(after)), 'count'),
            'drift_missed_moves': (missed, 'count'),
            'drift_moves': (MOVES, 'count'),
            'drift_repeat_change_p95_mm': (float(np.percentile(
                [s.change.translation_m * 1e3 for s in repeats], 95)), 'mm')}


if __name__ == '__main__':
    sys.exit(benchlib.main(run))
