"""Refusals of a user-frame calibration's data, in-process through the one path the service and
`cobot-calib user-frame` share (api.user_frame.calibrate): the cause, a message saying what to
do, nothing stored. The ROS side of the same refusals (the interface's constants, frame ids) is
test/nodes/test_user_frame_solver.py's."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cobot_calib_ros import store
from cobot_calib_ros.api import user_frame as api
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode as E
from cobot_calib_ros.core.user_frame.procedure import Gate
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file

CELL = load_cell(cell_file('sawyer_close'))
# A known user frame: rotated 30 deg about base z and tilted a little, offset in base [m].
T_TRUE = frames.make_transform(
    Rotation.from_euler('ZYX', [30.0, 1.5, -2.0], degrees=True).as_matrix(), [0.55, -0.12, 0.08])
# The paper's layout: a 0.2 x 0.15 m rectangle (P1 at the origin) and its centre [m].
P_USER = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.15, 0.0], [0.0, 0.15, 0.0],
                   [0.1, 0.075, 0.0]])
# Fixed measurement noise on the base points, up to ~19 um per point [m].
NOISE = 1e-6 * np.array([[12.0, -8.0, 5.0], [-10.0, 15.0, -7.0], [6.0, -4.0, -12.0],
                         [-9.0, -11.0, 8.0], [3.0, 9.0, 6.0]])
P_BASE = frames.apply(T_TRUE, P_USER) + NOISE
NAN = float('nan')
LINE = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
DUPLICATE = P_USER.copy()
DUPLICATE[3] = DUPLICATE[1]
BASE_DUPLICATE = P_BASE.copy()
BASE_DUPLICATE[4] = BASE_DUPLICATE[0]
USER_NAN = P_USER.copy()
USER_NAN[2, 1] = NAN
BASE_NAN = P_BASE.copy()
BASE_NAN[4, 2] = NAN
ONE_OFF = P_BASE.copy()
ONE_OFF[4, 2] += 3e-3          # the centre touched 3 mm high: RMS ~1.2 mm
# the service's defaults: 1 mm RMS, 1 % scale
GATE = Gate(max_rms_error=1e-3, max_scale_error=0.01)


@pytest.mark.parametrize('fields, code, words', [
    pytest.param({'user': P_USER[:2], 'base': P_BASE[:2]}, E.TOO_FEW_POINTS,
                 ['got 2 point', 'at least three'], id='two_points'),
    pytest.param({'user': np.zeros((0, 3)), 'base': np.zeros((0, 3))}, E.TOO_FEW_POINTS,
                 ['no points', 'points_user'], id='no_points'),
    pytest.param({'user': LINE, 'base': frames.apply(T_TRUE, LINE)}, E.DEGENERATE_POINTS,
                 ['collinear'], id='collinear'),
    pytest.param({'user': DUPLICATE, 'base': P_BASE}, E.DEGENERATE_POINTS,
                 ['user points P2 and P4 coincide'], id='duplicate_user'),
    pytest.param({'user': DUPLICATE, 'base': P_BASE, 'point_names': list('abcde')},
                 E.DEGENERATE_POINTS, ['user points b and d coincide'],
                 id='duplicate_named'),
    pytest.param({'user': P_USER, 'base': BASE_DUPLICATE}, E.DEGENERATE_POINTS,
                 ['base points P1 and P5 coincide', 'robot move'], id='duplicate_base'),
    pytest.param({'user': USER_NAN, 'base': P_BASE}, E.INVALID_INPUT,
                 ['user point P3', 'not finite'], id='nan_user'),
    pytest.param({'user': P_USER, 'base': BASE_NAN}, E.INVALID_INPUT,
                 ['base point P5', 'not finite'], id='nan_base'),
    pytest.param({'user': P_USER, 'base': P_BASE[:4]}, E.INVALID_INPUT,
                 ['5 user points and 4 base points'], id='count_mismatch'),
    pytest.param({'user': P_USER, 'base': np.zeros((0, 3))}, E.INVALID_INPUT,
                 ['5 user points and 0 base points'], id='no_base_points'),
    pytest.param({'point_names': ['P1', 'P2']}, E.INVALID_INPUT,
                 ['2 point names for 5 points'], id='names_mismatch'),
    pytest.param({'method': 'four_point'}, E.UNKNOWN_METHOD,
                 ["'four_point'", 'five_point_lsq', 'rigid'], id='unknown_method'),
    pytest.param({'user': np.zeros((0, 3)), 'base': np.zeros((0, 3)), 'method': 'bogus'},
                 E.UNKNOWN_METHOD, ["unknown method 'bogus'; one of: three_point,",
                                      'landmark_multi'], id='unknown_method_no_points'),
    pytest.param({'user': P_USER * 1e3, 'base': P_BASE * 1e3}, E.INVALID_INPUT,
                 ['the points look like millimetres', 'lengths are in metres'],
                 id='both_in_mm'),
    pytest.param({'user': np.zeros((0, 3)), 'base': np.zeros((0, 3)), 'point_names': ['P9']},
                 E.UNKNOWN_POINT, ['P9', 'P1', 'P5'], id='unknown_live_point'),
    pytest.param({'base': P_BASE * 1e3}, E.IMPLAUSIBLE_FIT,
                 ['RMS residual 111.7', 'max_rms_error', 'millimetres'], id='base_in_mm'),
    pytest.param({'base': P_BASE * 1e3, 'method': 'five_point_lsq'}, E.IMPLAUSIBLE_FIT,
                 ['scale 1000', 'max_scale_error', 'millimetres'], id='lsq_base_in_mm'),
    pytest.param({'base': P_BASE[[0, 2, 1, 3, 4]]}, E.IMPLAUSIBLE_FIT,
                 ['max_rms_error', 'same marker as its user point'], id='swapped_points'),
    pytest.param({'base': ONE_OFF}, E.IMPLAUSIBLE_FIT,    # accepted by calibrate()'s 10 mm
                 ['RMS residual', 'max_rms_error', 're-touch'], id='one_point_off'),
])
def test_bad_data_is_refused_with_a_reason_and_nothing_is_stored(tmp_path, fields, code, words):
    repo = store.open(tmp_path, cell='sawyer_close')
    request = api.Request(method=fields.get('method', ''), names=tuple(fields.get(
        'point_names', ())), p_user=fields.get('user', P_USER), p_base=fields.get('base', P_BASE),
        kinematics='nominal', gate=GATE)
    refused = api.calibrate(repo, CELL, request, stamp_ns=1)
    assert not refused and refused.code == code, refused
    for word in words:
        assert word in refused.message
    assert repo.user_frames.history() == []


def test_the_known_points_give_the_known_frame_within_their_noise(tmp_path):
    """The good call the refusals are told from: stored, active, T within the noise."""
    repo = store.open(tmp_path, cell='sawyer_close')
    done = api.calibrate(repo, CELL, api.Request(p_user=P_USER, p_base=P_BASE, gate=GATE),
                         stamp_ns=1)
    assert done and done.active and done.through == {}
    dt, dr = frames.transform_error(done.measured.fit.T_base_user, T_TRUE)
    assert dt < 1e-4 and dr < 1e-3, (dt, dr)
    assert repo.user_frames.active()['id'] == done.record['id']
