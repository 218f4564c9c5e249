"""The user-frame calibration's one path (core.user_frame.procedure + api.user_frame) and the
user-frame check (api.check), in-process over the simulated Sawyer cell (sim.robot.DirectRobot):
scored against the mock's ground truth (the true table and marker tops, its true arm and tool),
no node spun (issue 39.2)."""
from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.api import check as checks
from cobot_calib_ros.api import user_frame as api
from cobot_calib_ros.api.user_frame_file import calibrate_from_file
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.health_checks import PASS, RECALIBRATE
from cobot_calib_ros.core.robot_port import MoveFailed
from cobot_calib_ros.core.user_frame.procedure import touch_joints
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.sim.user_frame_run import moved_table

SIM = load_simulation(cell_file('sawyer_close'))
CELL = SIM.cell
NAMES = tuple(CELL.point_names)
TOPS = np.array([CELL.marker(n).nominal_top for n in SIM.world.point_names])


def _robot(sim=SIM, seed: int = 7) -> DirectRobot:
    return DirectRobot(SimRobot(sim, seed_offset=seed), sim.probe)


def _repo(tmp_path):
    return store.open(tmp_path, cell='sawyer_close')


def test_a_touched_frame_is_the_true_table_within_the_touch_noise_and_the_nominal_arm(tmp_path):
    """Through the nominal arm and tool (nothing calibrated): the touched points are the true
    marker tops within the touch noise (~0.1 mm) plus what the nominal model does not know of
    the arm and the 0.25 mm tool error; the frame follows within those."""
    repo = _repo(tmp_path)
    done = api.calibrate(repo, CELL, api.Request(names=NAMES, kinematics='nominal'),
                         stamp_ns=1, robot=_robot())
    assert done and done.stored and done.active, done
    assert done.through == {'kinematics': 'nominal', 'tcp': 'nominal'}
    assert 'nominal' in done.prerequisites
    true_tops = dict(zip(SIM.world.point_names, SIM.world.true_points_base()))
    errors = np.linalg.norm(done.measured.p_base - [true_tops[n] for n in NAMES], axis=1)
    assert errors.max() < 0.6e-3, errors
    dt, dr = frames.transform_error(done.measured.fit.T_base_user, SIM.world.T_base_user)
    assert dt < 0.3e-3 and dr < 2e-3, (dt, dr)
    assert repo.user_frames.active()['id'] == done.record['id']


def test_the_service_path_and_the_points_file_give_the_same_frame(tmp_path):
    """The same joints, once as the request's captures and once as a points file
    (`cobot-calib user-frame --points`): one FK, one fit, one record."""
    joints = touch_joints(_robot(seed=3), NAMES)
    live = api.calibrate(_repo(tmp_path / 'a'), CELL,
                         api.Request(names=NAMES, joints=joints, kinematics='nominal'),
                         stamp_ns=1)
    model_joints = list(SimRobot(SIM).model.joint_names)
    lines = [','.join(['name', 'user_x', 'user_y', 'user_z', *model_joints])]
    for name, q in zip(NAMES, joints):
        top = CELL.marker(name).nominal_top
        lines.append(','.join([name, *(repr(float(v)) for v in (*top, *q))]))
    points = tmp_path / 'points.csv'
    points.write_text('\n'.join(lines) + '\n')
    report = calibrate_from_file(_repo(tmp_path / 'b'), CELL, points, kinematics='nominal')
    assert live and report['active']
    assert_allclose(report['T_base_user'], live.measured.fit.T_base_user, rtol=0, atol=1e-12)
    assert report['measured_through'] == live.through


class _Unreachable:
    robot_seconds = 0.0

    def touch(self, name, approach=None):
        raise MoveFailed(f'{name} out of reach')


class _FullDisk:
    def active(self):
        return None

    def save_and_activate(self, record):
        raise OSError(28, 'No space left on device')


@pytest.mark.parametrize('request_, robot, frames_store, cause, words', [
    (api.Request(names=('P1', 'P9')), None, None, ErrorCode.UNKNOWN_POINT, ['P9']),
    (api.Request(), None, None, ErrorCode.TOO_FEW_POINTS, ['no points']),
    (api.Request(method='four_point'), None, None, ErrorCode.UNKNOWN_METHOD,
     ['four_point', 'landmark_multi']),
    (api.Request(names=NAMES, kinematics='no-such'), None, None, ErrorCode.INVALID_INPUT,
     ["kinematics 'no-such'", 'use latest, nominal']),
    (api.Request(names=NAMES), _Unreachable(), None, ErrorCode.MOTION_FAILED,
     ['capture at P1 failed', 'out of reach']),
    (api.Request(p_user=TOPS * 1e3, p_base=SIM.world.true_points_base() * 1e3), None, None,
     ErrorCode.INVALID_INPUT, ['look like millimetres']),
    (api.Request(p_user=TOPS, p_base=SIM.world.true_points_base() * 1e3), None, None,
     ErrorCode.IMPLAUSIBLE_FIT, ['max_rms_error', 'millimetres']),
    (api.Request(names=NAMES), _robot(), _FullDisk(), ErrorCode.STORAGE_FAILED,
     ['could not store', 'No space left']),
], ids=['unknown_point', 'no_points', 'unknown_method', 'unknown_kinematics',
        'touch_failed', 'points_in_mm', 'base_in_mm', 'disk_full'])
def test_a_refused_calibration_says_why_and_stores_nothing(tmp_path, request_, robot,
                                                           frames_store, cause, words):
    repo = _repo(tmp_path)
    refused = api.calibrate(repo, CELL, request_, stamp_ns=1, robot=robot,
                            frames_store=frames_store)
    assert not refused and refused.code == cause, refused
    assert all(w in refused.message for w in words), refused.message
    assert repo.user_frames.history() == []


def test_the_check_passes_on_the_calibrated_table_and_fails_once_it_moved(tmp_path):
    repo = _repo(tmp_path)
    frame = api.calibrate(repo, CELL, api.Request(names=NAMES), stamp_ns=1, robot=_robot())
    prepared = checks.prepare(checks.USER_FRAME, CELL, repo)
    assert prepared and prepared.against == frame.record['id']
    assert prepared.run(_robot(seed=51)).verdict == PASS
    moved = prepared.run(_robot(moved_table(SIM, [3e-4, 0, 0]), seed=52))
    assert moved.verdict == RECALIBRATE
    assert np.linalg.norm(moved.mean_error) == pytest.approx(3e-4, abs=0.8e-4)
    stored = checks.record(prepared, moved)
    assert stored['inputs']['against'] == frame.record['id']
    assert repo.checks.history()[0]['result']['verdict'] == RECALIBRATE


def test_a_check_without_a_calibrated_frame_or_of_unknown_points_is_refused(tmp_path):
    repo = _repo(tmp_path)
    none = checks.prepare(checks.USER_FRAME, CELL, repo)
    assert not none and none.code == ErrorCode.NO_CALIBRATION and 'calibrate first' in \
        none.message
    unknown = checks.prepare(checks.USER_FRAME, CELL, repo, points=('P1', 'Q7'))
    assert not unknown and unknown.code == ErrorCode.INVALID_INPUT and 'Q7' in unknown.message
    stopped = api.calibrate(repo, CELL, api.Request(names=NAMES), stamp_ns=1, robot=_robot())
    assert stopped
    failed = checks.prepare(checks.USER_FRAME, CELL, repo).run(_Unreachable())
    assert not failed and failed.code == ErrorCode.MOTION_FAILED
