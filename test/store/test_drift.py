"""Drift (core.drift, store.history) on fixed numbers and on the simulated cell whose table
moves 0.3 mm between two calibrations (issue 19 must-show 2), through the database."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core.drift import (change_covariance, DriftLimits, ERROR, frame_change,
                                        OK, WARN)
from cobot_calib_ros.core.frames import make_transform, rot_z
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import calibrate_user_frame, moved_table
from cobot_calib_ros.store.history import kinematic_changes, user_frame_steps
from cobot_calib_ros.store.records import UserFrameRecord

SIM = load_simulation(cell_file('sawyer_close'))
MM = 1e-3


def _cov(sigma_m, sigma_rad=1e-4):
    return np.diag([sigma_m ** 2] * 3 + [sigma_rad ** 2] * 3)


@pytest.mark.parametrize('move_mm, sigma_mm, level', [
    (0.5, 0.01, WARN),      # significant and beyond 0.2 mm
    (2.0, 0.01, ERROR),     # beyond 1 mm
    (0.1, 0.001, OK),       # significant, but within the tolerance
    (0.5, 0.2, OK),         # beyond the tolerance, but 2.5 sigma: noise
])
def test_a_change_needs_k_sigma_and_the_tolerance(move_mm, sigma_mm, level):
    T0 = make_transform(rot_z(0.3), [0.4, -0.1, 0.0])
    T1 = T0.copy()
    T1[:3, 3] += np.array([0.6, 0.8, 0.0]) * move_mm * MM
    change = frame_change(T0, T1, _cov(sigma_mm * MM))
    assert change.translation_m == pytest.approx(move_mm * MM)
    assert change.sigma_translation_m == pytest.approx(sigma_mm * MM)
    assert change.level == level
    assert ('recalibrate' in change.message) == (level != OK)


def test_a_rotation_alone_raises_the_alarm_and_unknown_noise_raises_none():
    T0 = np.eye(4)
    T1 = make_transform(rot_z(2e-3), [0, 0, 0])
    assert frame_change(T0, T1, _cov(1e-5, 1e-5)).level == WARN       # 2 mrad > 1 mrad
    assert frame_change(T0, T1, np.full((6, 6), np.inf)).level == OK


def test_change_covariance_keeps_only_the_noise_both_measurements_share():
    """Points with a common systematic error (the same in both) and no noise: the change's
    covariance is zero, so the fit's residuals (here 0.1 mm) do not count."""
    rng = np.random.default_rng(2)
    p_user = rng.uniform(-0.2, 0.2, (5, 3))
    systematic = rng.normal(0, 1e-4, (5, 3))
    T0 = make_transform(rot_z(0.2), [0.5, 0.1, 0.0])
    p0 = p_user @ T0[:3, :3].T + T0[:3, 3] + systematic
    assert np.allclose(change_covariance(T0, p0, p0 + [0.3e-3, 0, 0]), 0.0, atol=1e-20)
    noisy = p0 + rng.normal(0, 2e-5, (5, 3))
    sigma_t = math.sqrt(np.trace(change_covariance(T0, p0, noisy)[:3, :3]) / 3)
    assert 0.3 * 2e-5 < sigma_t < 3 * 2e-5


def _store_calibration(repo, sim, seed, stamp_ns):
    run = calibrate_user_frame(sim, seed)
    record = UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user, run.p_base,
                                      ('base', 'user'), stamp_ns)
    record.id = f'uf-{stamp_ns:04d}'
    repo.user_frames.save_and_activate(record)


def test_repeats_raise_nothing_and_a_moved_table_warns_within_one_calibration(tmp_path):
    """Must-show 2 on the simulated Sawyer cell: 50 repeat calibrations (new touches each)
    raise no alarm; the table moved 0.3 mm along x, y or z between two calibrations raises
    WARN at the first calibration after the move."""
    repo = store.open(tmp_path / 'cell', f'sqlite:///{tmp_path / "r.sqlite"}', 'cell_07')
    for k in range(51):
        _store_calibration(repo, SIM, 100 + k, k)
    steps = user_frame_steps(store.open(tmp_path / 'cell', f'sqlite:///{tmp_path / "r.sqlite"}',
                                        'cell_07').user_frames.history())
    assert len(steps) == 51 and steps[0].change is None
    assert [s.record['id'] for s in steps[1:] if s.change.level != OK] == []
    for axis in range(3):
        offset = np.zeros(3)
        offset[axis] = 0.3 * MM
        _store_calibration(repo, moved_table(SIM, offset), 300 + axis, 100 + 2 * axis)
        _store_calibration(repo, SIM, 400 + axis, 101 + 2 * axis)      # and moved back
    steps = user_frame_steps(repo.user_frames.history())[51:]
    assert [s.change.level for s in steps] == [WARN] * 6
    assert all(0.2 * MM < s.change.translation_m < 0.4 * MM for s in steps)
    assert 'user frame moved 0.' in steps[0].change.message


def test_a_change_touched_with_another_tcp_says_so():
    """Two calibrations of the same table touched with two TCP calibrations: the change's
    message names both (the frame's change then holds the tool's); the same TCP, or one not
    recorded (given points, records before the field), adds nothing."""
    records = []
    for seed, tcp in ((7, 'nominal'), (8, 'tcp-tool0-2'), (9, 'tcp-tool0-2'), (10, '')):
        run = calibrate_user_frame(SIM, seed)
        records.append(UserFrameRecord.from_fit(run.fit, None, run.names, run.p_user,
                                                run.p_base, ('base', 'user'), seed,
                                                tcp=tcp).to_dict())
        records[-1]['id'] = f'uf-{seed}'
    messages = [s.change.message for s in user_frame_steps(records)[1:]]
    assert messages[0].endswith('; touched with TCP tcp-tool0-2, uf-7 with TCP nominal: the '
                                "change holds the tool's"), messages[0]
    assert ['TCP' in m for m in messages] == [True, False, False]


def test_kinematic_changes_in_standard_errors():
    prev = {'result': {'free': ['a', 'b'], 'values': [1.0, 2.0], 'std': [0.3, 0.4]}}
    new = {'result': {'free': ['b', 'c'], 'values': [3.0, 0.0], 'std': [0.3, 0.1]}}
    change, = kinematic_changes(prev, new)
    assert (change.name, change.change, change.sigma, change.z) == ('b', 1.0, 0.5, 2.0)
