"""calibrate_user_frame with the landmark methods (issue 11) on the session suite (cell
sawyer_close, mock_camera + landmark_detector running): the wrist camera looks at the table's
fiducials and the solver derives the user frame; scored against the mock's true user frame."""
import json
import time

from cobot_calib_msgs.msg import UserFrameCalibration
from cobot_calib_msgs.srv import CalibrateUserFrame, GetGroundTruth
import numpy as np
import pytest

from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.ros import convert, qos
from rosutil import call, cli, set_parameter

Res = CalibrateUserFrame.Response
Req = CalibrateUserFrame.Request
LANDMARK_TIMEOUT = 600.0      # [s] 18 views on a loaded machine
RESULTS = {}
# [s] the solver's hold at each view in these tests (its default 0.5: 9 s of the 18 views'
# ~15 s). The mock's joint noise (2e-6 rad) makes 0.2 s of 1 kHz samples as good; every frame
# here is still scored on the mock's truth with the same bounds.
HOLD = 0.2


@pytest.fixture(scope='module', autouse=True)
def short_holds(ros):
    node = '/user_frame_solver'
    assert set_parameter(ros, node, 'capture_duration', HOLD).successful
    yield
    assert set_parameter(ros, node, 'capture_duration', 0.5).successful     # its default


def _truth(ros):
    truth = call(ros, GetGroundTruth, 'get_ground_truth')
    return truth, convert.transform_to_matrix(truth.user_frame)


def _errors(response, T_true):
    T = convert.transform_to_matrix(response.calibration.transform)
    return frames.transform_error(T, T_true)


def _explicit_rigid(ros):
    """Points given in the request (a few mm off the truth): the plain rigid fit. It becomes
    the active calibration, which the landmark methods plan their views by."""
    truth, T_true = _truth(ros)
    p_base = convert.points_to_array(truth.points_base) + np.array([0.002, -0.001, 0.0005])
    res = call(ros, CalibrateUserFrame, 'calibrate_user_frame', 10.0, method=Req.METHOD_RIGID,
               points_user=truth.points_user, points_base=convert.array_to_points(p_base),
               point_names=list(truth.point_names))
    assert res.error_code == Res.SUCCESS, res.message
    assert res.calibration.method == 'rigid'
    assert [r.name for r in res.calibration.residuals] == list(truth.point_names)
    assert _errors(res, T_true)[0] < 0.005
    return res


def test_explicit_rigid_still_works(ros):
    res = _explicit_rigid(ros)
    assert len(res.calibration.residuals) == 5


def _landmark(ros, method, **extra):
    _explicit_rigid(ros)        # whatever earlier tests left active: a frame to plan by
    _, T_true = _truth(ros)
    t0 = time.monotonic()
    res = call(ros, CalibrateUserFrame, 'calibrate_user_frame', LANDMARK_TIMEOUT,
               method=method, point_names=['ignored'], **extra)
    seconds = time.monotonic() - t0
    assert res.error_code == Res.SUCCESS, res.message
    assert res.calibration.method == method
    pos, ang = _errors(res, T_true)
    RESULTS[method] = (pos, ang, seconds)
    print(f'\n{method}: frame error {pos * 1e3:.3f} mm / {ang * 1e3:.3f} mrad, '
          f'{seconds:.1f} s, {len(res.calibration.residuals)} points, rms '
          f'{res.calibration.rms_residual * 1e3:.3f} mm; {res.message}')
    return res, pos, ang


def test_landmark_single(ros):
    res, pos, ang = _landmark(ros, Req.METHOD_LANDMARK_SINGLE)
    assert [r.name for r in res.calibration.residuals] == ['L0', 'L0+x', 'L0+y']
    assert pos < 0.02 and ang < 0.03


def test_the_readme_call_answers_with_a_line_per_view(ros):
    """`cobot-calib call calibrate_user_frame "{method: landmark_multi}"` as the README has it:
    no client timeout cuts it short (~10 s), and every view shows while the robot moves."""
    _explicit_rigid(ros)
    done = cli('call', 'calibrate_user_frame', '{method: landmark_multi}', '--json',
               timeout=LANDMARK_TIMEOUT)
    assert done.returncode == 0, done.stderr
    res = json.loads(done.stdout)
    assert res['error_code'] == Res.SUCCESS, res['message']
    views = [line for line in done.stderr.splitlines() if line.startswith('  capture ')]
    # every fiducial from three views: six markers x 3, in the order they are taken
    assert len(views) == 18, done.stderr
    assert all(line.split(': ')[1].startswith('landmark_') for line in views)


def test_a_client_that_stops_waiting_says_the_call_may_still_complete(ros):
    """--answer-timeout ends the wait, not the calibration: the message says so and names
    where the result shows, and the result does become the active calibration. That result
    is landmark_multi's with a surface fit, scored here on the truth (one calibration for
    both: each takes 18 views)."""
    _explicit_rigid(ros)        # whatever earlier tests left active: a frame to plan by
    _, T_true = _truth(ros)
    latched = []
    sub = ros.create_subscription(UserFrameCalibration, '/user_frame', latched.append,
                                  qos.LATCHED)
    try:
        assert spin_until(ros, lambda: latched, 10.0, ros.executor_for_tests)
        before = latched[-1].id
        done = cli('call', 'calibrate_user_frame',
                   '{method: landmark_multi, fit_surface: true}',
                   '--answer-timeout', '2', timeout=60)      # 18 holds of HOLD: > 3 s
        assert done.returncode == 1, done.stdout + done.stderr
        assert done.stderr.splitlines()[-1] == (
            'no answer from /calibrate_user_frame within 2 s; the call was sent and may still '
            'complete on the server: see `cobot-calib echo user_frame --once` (the active '
            'calibration) or `cobot-calib call list_calibrations`')
        assert spin_until(ros, lambda: latched[-1].id != before, LANDMARK_TIMEOUT,
                          ros.executor_for_tests)
    finally:
        ros.destroy_subscription(sub)
    multi = latched[-1]
    assert multi.method == 'landmark_multi'
    assert len(multi.residuals) >= 3
    # six fiducial centres on the table: an order-1 height correction, named by marker
    assert multi.surface.valid and len(multi.surface.coefficients) == 3
    pos, ang = frames.transform_error(convert.transform_to_matrix(multi.transform), T_true)
    print(f'\nlandmark_multi: frame error {pos * 1e3:.3f} mm / {ang * 1e3:.3f} mrad, '
          f'{len(multi.residuals)} points, rms {multi.rms_residual * 1e3:.3f} mm')
    assert pos < 0.01 and ang < 0.02
    if Req.METHOD_LANDMARK_SINGLE in RESULTS:
        single = RESULTS[Req.METHOD_LANDMARK_SINGLE]
        assert pos < single[0] + 0.001, (RESULTS, 'multi no better than single')
