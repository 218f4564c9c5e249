"""user_frame_solver across processes: refusals with a reason, fits, conversion, history."""
import math

from cobot_calib_msgs.msg import UserFrameCalibration
from cobot_calib_msgs.srv import CalibrateUserFrame, ConvertPoints, ListCalibrations
import numpy as np
import pytest
from rcl_interfaces.srv import GetParameters
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from scipy.spatial.transform import Rotation
from tf2_msgs.msg import TFMessage

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros import convert
from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.paths import cell_file
from rosutil import call, listen_late, set_parameter, STARTUP_TIMEOUT, STOP_TIMEOUT

Res = CalibrateUserFrame.Response
Conv = ConvertPoints.Response

# A known user frame: rotated 30 deg about base z and tilted a little, offset in base [m].
R_TRUE = Rotation.from_euler('ZYX', [30.0, 1.5, -2.0], degrees=True).as_matrix()
T_TRUE = frames.make_transform(R_TRUE, [0.55, -0.12, 0.08])
# The paper's layout: a 0.2 x 0.15 m rectangle (P1 at the origin) and its centre [m].
P_USER = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.15, 0.0], [0.0, 0.15, 0.0],
                   [0.1, 0.075, 0.0]])
# Fixed measurement noise on the base points, up to ~19 um per point [m].
NOISE = 1e-6 * np.array([[12.0, -8.0, 5.0], [-10.0, 15.0, -7.0], [6.0, -4.0, -12.0],
                         [-9.0, -11.0, 8.0], [3.0, 9.0, 6.0]])
P_BASE = frames.apply(T_TRUE, P_USER) + NOISE
NOISE_MAX = float(np.linalg.norm(NOISE, axis=1).max())            # [m]
NOISE_RMS = float(np.sqrt((np.linalg.norm(NOISE, axis=1) ** 2).mean()))   # [m]
# What that noise can do to a least-squares pose: tilt it by at most ~2 noise norms over the
# half short side (0.075 m), and shift the user origin by the noise plus that tilt times the
# origin's distance from the centroid (0.125 m).
ROT_TOL = 2.0 * NOISE_MAX / 0.075                                  # [rad]
TRANS_TOL = NOISE_MAX + ROT_TOL * float(np.linalg.norm(P_USER.mean(axis=0)))   # [m]
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
TF_LISTENER = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
NAN = float('nan')
ORPHAN = 'orphan.user_frame_solver'
BAD_FRAME = 'bad frame!'


def _calibrate(ros, name='calibrate_user_frame', timeout=10.0, user=P_USER, base=P_BASE,
               **fields):
    return call(ros, CalibrateUserFrame, name, timeout,
                 points_user=convert.array_to_points(user),
                 points_base=convert.array_to_points(base), **fields)


def _convert(ros, name, points, calibration_id=''):
    return call(ros, ConvertPoints, name, points=convert.array_to_points(points),
                 calibration_id=calibration_id)


def _history(ros, name='list_calibrations', max_count=0):
    return call(ros, ListCalibrations, name, max_count=max_count).calibrations


def _matrix(calibration) -> np.ndarray:
    return np.array(calibration.matrix).reshape(4, 4)


def _pose_error(T, T_ref) -> tuple[float, float]:
    """(rotation [rad], translation [m]) between two rigid transforms."""
    angle = Rotation.from_matrix(T[:3, :3] @ T_ref[:3, :3].T).magnitude()
    return float(angle), float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3]))


def _rms(vectors) -> float:
    return float(np.sqrt((np.linalg.norm(vectors, axis=1) ** 2).mean()))


def _assert_serves_a_good_call(ros, suite, process='user_frame_solver',
                               name='calibrate_user_frame'):
    assert process not in suite.failed(), suite.log_tail(process)
    res = _calibrate(ros, name, method='rigid')
    assert res.error_code == Res.SUCCESS, res.message
    assert res.calibration.id and len(res.calibration.residuals) == len(P_USER)
    return res


@pytest.fixture(scope='module')
def fits(ros):
    """One rigid and one five_point_lsq calibration of the known points (in that order)."""
    rigid = _calibrate(ros, method='rigid')
    lsq = _calibrate(ros, method='five_point_lsq')
    return {'rigid': rigid, 'five_point_lsq': lsq}


@pytest.fixture(scope='module')
def spare(ros, tmp_path_factory):
    """More user_frame_solvers where no mock_robot or monitor exists, started together:
    /orphan (must stay up and exit cleanly), /scratch (may be crashed by a test) and /frames
    (started with an invalid user_frame parameter)."""
    extra = {'frames': {'user_frame': BAD_FRAME}}
    running = launcher.Suite(tmp_path_factory.mktemp('spare_logs'))
    running.start([launcher.NodeSpec('user_frame_solver', namespace=ns, params={
        'cell_file': str(cell_file('sawyer_close')),
        'data_dir': str(tmp_path_factory.mktemp(f'{ns}_results')), **extra.get(ns, {})})
        for ns in ('orphan', 'scratch', 'frames')])
    wanted = {'/orphan/calibrate_user_frame', '/scratch/user_to_robot',
              '/frames/calibrate_user_frame', '/frames/user_frame_solver/set_parameters'}
    if not spin_until(ros, lambda: wanted <= {n for n, _ in ros.get_service_names_and_types()},
                      STARTUP_TIMEOUT, ros.executor_for_tests):
        running.stop()
        logs = '\n'.join(f'--- {n}\n{running.log_tail(n)}' for n in running.processes)
        pytest.fail(f'spare user_frame_solvers did not come up in {STARTUP_TIMEOUT} s:\n{logs}')
    yield running
    codes = running.stop(STOP_TIMEOUT)
    assert codes[ORPHAN] == 0, f'/orphan/user_frame_solver did not exit cleanly: {codes}'


# -------------------------------------------------------------------------- refusals

GOOD_NAMES = [f'P{i + 1}' for i in range(5)]
ONE_OFF = P_BASE.copy()
ONE_OFF[4, 2] += 3e-3          # the centre touched 3 mm high: RMS ~1.2 mm


# The ROS side of a refusal: the method checked first, a fit's refusal answered with the
# interface's constant, frame ids from the request or the parameters. Every other refusal of
# the data is the api's: test/api/test_user_frame_refusals.py, in-process.
@pytest.mark.parametrize('fields, code, words', [
    pytest.param({'user': np.zeros((0, 3)), 'base': np.zeros((0, 3)), 'method': 'bogus'},
                 Res.UNKNOWN_METHOD, ["unknown method 'bogus'; one of: three_point,",
                                      'landmark_multi'], id='unknown_method_no_points'),
    pytest.param({'base': P_BASE * 1e3}, Res.IMPLAUSIBLE_FIT,
                 ['RMS residual 111.7', 'max_rms_error', 'millimetres'], id='base_in_mm'),
    pytest.param({'user_frame': BAD_FRAME}, Res.INVALID_INPUT,
                 ['request user_frame', repr(BAD_FRAME), 'letters, digits'], id='bad_user_frame'),
    pytest.param({'base_frame': '/world'}, Res.INVALID_INPUT,
                 ['request base_frame', 'no leading /'], id='leading_slash'),
    pytest.param({'user_frame': 'base_link'}, Res.INVALID_INPUT,
                 ['parameter base_frame and request user_frame', "'base_link'", 'own'],
                 id='user_frame_is_base_frame'),
])
def test_bad_request_is_refused_with_a_reason_and_the_node_serves_on(ros, suite, fields, code,
                                                                       words):
    before = [c.id for c in _history(ros)]
    res = _calibrate(ros, **fields)
    assert res.error_code == code, res.message
    for word in words:
        assert word in res.message
    assert res.calibration.id == '' and len(res.calibration.residuals) == 0
    assert [c.id for c in _history(ros)] == before            # nothing stored
    _assert_serves_a_good_call(ros, suite)


def test_implausible_fit_is_neither_stored_nor_published(ros, suite):
    good = _assert_serves_a_good_call(ros, suite).calibration
    res = _calibrate(ros, base=P_BASE * 1e3)
    assert res.error_code == Res.IMPLAUSIBLE_FIT, res.message
    assert res.calibration.id == ''
    assert _history(ros, max_count=1)[0].id == good.id
    assert call(ros, ListCalibrations, 'list_calibrations').active_id == good.id
    latched = listen_late(ros, UserFrameCalibration, 'user_frame', LATCHED,
                          lambda got: bool(got) and got[-1].id == good.id)
    assert latched and latched[-1].id == good.id
    tf = listen_late(ros, TFMessage, '/tf_static', TF_LISTENER,
                     lambda got: any(t == good.transform for m in got for t in m.transforms))
    assert tf and [t for t in tf[-1].transforms if t.child_frame_id == 'user_frame'] == \
        [good.transform]
    conv = _convert(ros, 'user_to_robot', P_USER)
    assert conv.error_code == Conv.SUCCESS and good.id in conv.message, conv.message


def _get_parameter(ros, node, name) -> str:
    return call(ros, GetParameters, f'{node}/get_parameters', names=[name]).values[0].string_value


def test_invalid_frame_parameter_refuses_calibrations_until_it_is_set_right(ros, spare):
    node = '/frames/user_frame_solver'
    res = _calibrate(ros, '/frames/calibrate_user_frame')
    assert res.error_code == Res.INVALID_INPUT, res.message
    assert 'parameter user_frame' in res.message and repr(BAD_FRAME) in res.message
    assert _history(ros, '/frames/list_calibrations') == []
    named = _calibrate(ros, '/frames/calibrate_user_frame', user_frame='table')
    assert named.error_code == Res.SUCCESS, named.message           # the request's own frame
    assert named.calibration.transform.child_frame_id == 'table'
    for name, value, words in [('user_frame', 'still bad!', ['user_frame', "'still bad!'"]),
                               ('base_frame', '/world', ['base_frame', 'no leading /']),
                               ('base_frame', '', ['base_frame', 'must not be empty'])]:
        result = set_parameter(ros, node, name, value)
        assert not result.successful, (name, value)
        assert all(w in result.reason for w in words), result.reason
    assert _get_parameter(ros, node, 'base_frame') == 'base_link'     # nothing changed
    same = set_parameter(ros, node, 'user_frame', 'base_link')
    assert not same.successful and 'both' in same.reason, same.reason
    fixed = set_parameter(ros, node, 'user_frame', 'work_table')
    assert fixed.successful, fixed.reason
    res = _calibrate(ros, '/frames/calibrate_user_frame')
    assert res.error_code == Res.SUCCESS, res.message
    assert (res.calibration.transform.header.frame_id,
            res.calibration.transform.child_frame_id) == ('base_link', 'work_table')
    assert 'frames.user_frame_solver' not in spare.failed()


def test_plausibility_limits_are_the_node_parameters(ros, spare):
    """max_rms_error [m] and max_scale_error [1] reach the sanity gate, at run time."""
    node, service = '/frames/user_frame_solver', '/frames/calibrate_user_frame'
    stretched = frames.apply(T_TRUE, P_USER * 1.02) + NOISE        # a 2 % larger layout
    cases = [('max_scale_error', 0.03, {'base': stretched, 'method': 'five_point_lsq'}),
             ('max_rms_error', 0.002, {'base': ONE_OFF})]
    for name, looser, fields in cases:
        refused = _calibrate(ros, service, user_frame='table', **fields)
        assert refused.error_code == Res.IMPLAUSIBLE_FIT and name in refused.message, \
            refused.message
        assert set_parameter(ros, node, name, looser).successful
        accepted = _calibrate(ros, service, user_frame='table', **fields)
        assert accepted.error_code == Res.SUCCESS, accepted.message
    out_of_range = set_parameter(ros, node, 'max_rms_error', 0.5)
    assert not out_of_range.successful


def test_failed_live_capture_says_what_to_start(ros, spare):
    """No move_to under /orphan: the node waits for the server (ros.robot_calls.SERVER_WAIT;
    bench/bench_waits.py times it), then refuses naming what to start."""
    empty = _convert(ros, '/orphan/user_to_robot', P_USER)
    assert empty.error_code == Conv.NO_CALIBRATION, empty.message
    assert 'calibrate_user_frame' in empty.message
    res = call(ros, CalibrateUserFrame, '/orphan/calibrate_user_frame', timeout=30.0,
                point_names=['P1', 'P2', 'P3'])
    assert res.error_code == Res.CAPTURE_FAILED, res.message
    assert 'P1' in res.message and 'move_to' in res.message and 'mock_robot' in res.message
    assert 'not available' in res.message             # its wait for the server ran out
    assert res.calibration.id == ''
    assert ORPHAN not in spare.failed()
    assert _history(ros, '/orphan/list_calibrations') == []
    good = _calibrate(ros, '/orphan/calibrate_user_frame', method='rigid')
    assert good.error_code == Res.SUCCESS, good.message
    assert [c.id for c in _history(ros, '/orphan/list_calibrations')] == [good.calibration.id]


def test_malformed_calibration_id_is_refused_not_fatal(ros, spare):
    assert _history(ros, '/scratch/list_calibrations') == []      # up and reachable
    res = call(ros, ConvertPoints, '/scratch/user_to_robot', timeout=3.0,
                calibration_id='bad id!', points=convert.array_to_points(P_USER))
    assert res.error_code == Conv.INVALID_INPUT, res.message
    assert 'bad id!' in res.message and 'must match' in res.message
    assert 'scratch.user_frame_solver' not in spare.failed()


# -------------------------------------------------------------------------- good fits


def test_rigid_fit_recovers_the_known_transform(fits):
    res = fits['rigid']
    assert res.error_code == Res.SUCCESS, res.message
    cal = res.calibration
    assert cal.method == 'rigid' and cal.id.endswith('-rigid')
    assert (cal.transform.header.frame_id, cal.transform.child_frame_id) == \
        ('base_link', 'user_frame')
    T = convert.transform_to_matrix(cal.transform)
    rot, trans = _pose_error(T, T_TRUE)
    assert rot < ROT_TOL and trans < TRANS_TOL, (rot, trans)
    assert len(cal.residuals) == 5
    assert [r.name for r in cal.residuals] == GOOD_NAMES
    # least squares: no worse than the true transform, which leaves exactly the noise
    assert 0.0 < cal.rms_residual <= NOISE_RMS
    assert cal.max_residual == pytest.approx(max(r.residual_norm for r in cal.residuals))
    np.testing.assert_allclose(_matrix(cal), T, atol=1e-12)
    np.testing.assert_allclose(_matrix(cal)[3], [0, 0, 0, 1])
    # the residuals it reports are M p_user - p_base
    residuals = np.array([[r.residual.x, r.residual.y, r.residual.z] for r in cal.residuals])
    np.testing.assert_allclose(residuals, frames.apply(T, P_USER) - P_BASE, atol=1e-12)
    assert _rms(residuals) == pytest.approx(cal.rms_residual, rel=1e-9)
    np.testing.assert_allclose([cal.scale_x, cal.scale_y, cal.scale_z], 1.0, atol=1e-12)


def test_five_point_lsq_returns_the_affine_matrix_it_fitted(fits):
    res = fits['five_point_lsq']
    assert res.error_code == Res.SUCCESS, res.message
    assert 'coplanar' in res.message
    cal = res.calibration
    assert cal.method == 'five_point_lsq' and len(cal.residuals) == 5
    T = convert.transform_to_matrix(cal.transform)
    rot, trans = _pose_error(T, T_TRUE)
    assert rot < ROT_TOL and trans < TRANS_TOL, (rot, trans)
    M = _matrix(cal)
    T_rigid = convert.transform_to_matrix(fits['rigid'].calibration.transform)
    assert np.abs(M - T_rigid).max() > 1e-6             # affine, not the rigid fit
    assert np.abs(M - T).max() > 1e-6                   # nor its own nearest rotation
    np.testing.assert_allclose(M[3], [0, 0, 0, 1])
    mapped = frames.apply(M, P_USER) - P_BASE
    assert _rms(mapped) == pytest.approx(cal.rms_residual, rel=1e-9)
    residuals = np.array([[r.residual.x, r.residual.y, r.residual.z] for r in cal.residuals])
    np.testing.assert_allclose(residuals, mapped, atol=1e-12)
    # more freedom than rigid: fits the points at least as well
    assert 0.0 < cal.rms_residual <= fits['rigid'].calibration.rms_residual
    assert _rms(frames.apply(T, P_USER) - P_BASE) > cal.rms_residual
    np.testing.assert_allclose([cal.scale_x, cal.scale_y, cal.scale_z],
                               np.linalg.norm(M[:3, :3], axis=0), rtol=1e-9)


# -------------------------------------------------------------------------- conversion


def test_user_to_robot_with_the_latest_calibration_and_back(ros):
    res = _calibrate(ros, method='rigid')
    assert res.error_code == Res.SUCCESS, res.message
    cal = res.calibration
    to_base = _convert(ros, 'user_to_robot', P_USER)
    assert to_base.error_code == Conv.SUCCESS, to_base.message
    assert cal.id in to_base.message
    base = convert.points_to_array(to_base.points)
    norms = np.linalg.norm(base - P_BASE, axis=1)
    assert np.all(norms <= np.array([r.residual_norm for r in cal.residuals]) + 1e-9)
    np.testing.assert_allclose(
        base - P_BASE, [[r.residual.x, r.residual.y, r.residual.z] for r in cal.residuals],
        atol=1e-9)
    back = _convert(ros, 'robot_to_user', base)
    assert back.error_code == Conv.SUCCESS, back.message
    np.testing.assert_allclose(convert.points_to_array(back.points), P_USER, atol=1e-9)


def test_conversion_by_id_uses_the_affine_matrix_and_inverts_it(ros, fits):
    cal = fits['five_point_lsq'].calibration
    to_base = _convert(ros, 'user_to_robot', P_USER, cal.id)
    assert to_base.error_code == Conv.SUCCESS, to_base.message
    assert cal.id in to_base.message
    base = convert.points_to_array(to_base.points)
    np.testing.assert_allclose(base, frames.apply(_matrix(cal), P_USER), atol=1e-9)
    probe = np.array([[0.05, 0.02, 0.01], [0.3, -0.1, -0.02]])      # off the fitted points
    there = convert.points_to_array(_convert(ros, 'user_to_robot', probe, cal.id).points)
    back = _convert(ros, 'robot_to_user', there, cal.id)
    assert back.error_code == Conv.SUCCESS, back.message
    np.testing.assert_allclose(convert.points_to_array(back.points), probe, atol=1e-9)


@pytest.mark.parametrize('service', ['user_to_robot', 'robot_to_user'])
def test_conversion_refuses_nan_and_unknown_ids(ros, suite, fits, service):
    bad = _convert(ros, service, [[0.1, NAN, 0.0]])
    assert bad.error_code == Conv.INVALID_INPUT and 'NaN' in bad.message, bad.message
    assert len(bad.points) == 0
    inf = _convert(ros, service, [[0.1, 0.0, math.inf]])
    assert inf.error_code == Conv.INVALID_INPUT and 'inf' in inf.message, inf.message
    missing = _convert(ros, service, P_USER, 'no-such-calibration')
    assert missing.error_code == Conv.NO_CALIBRATION, missing.message
    assert 'no-such-calibration' in missing.message and len(missing.points) == 0
    assert 'user_frame_solver' not in suite.failed()
    ok = _convert(ros, service, P_USER, fits['rigid'].calibration.id)
    assert ok.error_code == Conv.SUCCESS and len(ok.points) == 5, ok.message


# -------------------------------------------------------------------------- history


def test_list_calibrations_is_newest_first(ros, fits):
    latest = _calibrate(ros, method='three_point').calibration
    history = _history(ros)
    ids = [c.id for c in history]
    assert ids[0] == latest.id
    assert fits['rigid'].calibration.id in ids and fits['five_point_lsq'].calibration.id in ids
    assert ids.index(fits['five_point_lsq'].calibration.id) < \
        ids.index(fits['rigid'].calibration.id)
    stamps = [c.stamp.sec * 10**9 + c.stamp.nanosec for c in history]
    assert stamps == sorted(stamps, reverse=True) and len(set(ids)) == len(ids)
    assert [c.id for c in _history(ros, max_count=2)] == ids[:2]
    stored = history[ids.index(fits['rigid'].calibration.id)]
    np.testing.assert_allclose(stored.matrix, fits['rigid'].calibration.matrix, atol=0)


def test_late_subscriber_gets_the_latest_calibration(ros):
    latest = _calibrate(ros, method='robust').calibration
    got = []
    sub = ros.create_subscription(UserFrameCalibration, 'user_frame', got.append, LATCHED)
    try:
        spin_until(ros, lambda: bool(got), 10.0, ros.executor_for_tests)
    finally:
        ros.destroy_subscription(sub)
    assert got, 'no calibration on the latched user_frame topic'
    assert got[-1].id == latest.id and got[-1].method == 'robust'
    np.testing.assert_allclose(got[-1].matrix, latest.matrix, atol=0)
    assert len(got[-1].residuals) == 5


def test_parameters_read_once_refuse_set_parameters_with_the_reason(ros):
    """data_dir and cell_file are read at start-up: a change is refused, not silently kept."""
    for node, name in [('/user_frame_solver', 'data_dir'), ('/user_frame_solver', 'cell_file'),
                       ('/repeatability_trial', 'data_dir'), ('/mock_robot', 'cell_file')]:
        before = _get_parameter(ros, node, name)
        result = set_parameter(ros, node, name, '/tmp/elsewhere')
        assert not result.successful, (node, name)
        assert 'read-only' in result.reason, result.reason
        assert _get_parameter(ros, node, name) == before


def test_a_moved_frame_raises_the_drift_warning_on_diagnostics(ros):
    """Issue 19: the same points measured 0.5 mm further along x than by the calibration
    before: 'user_frame_solver: drift' goes WARN (beyond 3 standard errors, here 0: the
    same noise, and 0.2 mm) naming the move; measured again without a move: OK."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    latest = {}

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name == 'user_frame_solver: drift':
                latest['status'] = status

    def drift_after(base):
        assert _calibrate(ros, base=base).error_code == Res.SUCCESS
        latest.clear()
        spin_until(ros, lambda: 'status' in latest, 5.0, ros.executor_for_tests)
        return latest['status']

    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    try:
        drift_after(P_BASE)
        moved = drift_after(P_BASE + [0.5e-3, 0.0, 0.0])
        assert moved.level == DiagnosticStatus.WARN, moved.message
        assert moved.message.startswith('user frame moved 0.500 mm') and \
            'recalibrate' in moved.message
        again = drift_after(P_BASE + [0.5e-3, 0.0, 0.0])
        assert again.level == DiagnosticStatus.OK, again.message
    finally:
        ros.destroy_subscription(sub)
