"""The robot and camera ports (core.robot_port) on the in-process simulation (sim.robot.DirectRobot,
sim.camera.DirectCamera), and the landmark-frame procedure over them
(core.landmarks.views.measure_frame) against the simulation's ground truth."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.landmarks import views
from cobot_calib_ros.core.robot_port import (CameraPort, CaptureFailed, check_cancel, MoveFailed,
                                             never, RobotPort, Stopped)
from cobot_calib_ros.core.sensors.probe import ReadingStatus
from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

SIM = load_simulation(cell_file('sawyer_close'))


def _ports(seed: int = 4, boards: bool = False):
    arm = SimRobot(SIM, seed_offset=seed)
    return arm, DirectRobot(arm, SIM.probe), DirectCamera(SimCamera(SIM, arm), arm, boards)


def _public(protocol) -> set[str]:
    return {n for n in vars(protocol) if not n.startswith('_')} | set(
        getattr(protocol, '__annotations__', {}))


def test_the_simulation_implements_both_ports():
    _, robot, camera = _ports()
    assert _public(RobotPort) == {'robot_seconds', 'move_joints', 'move_to_pose', 'touch',
                                  'capture', 'probe', 'measure_position'}
    for name in _public(RobotPort):
        assert hasattr(robot, name), name
    for name in _public(CameraPort):
        assert callable(getattr(camera, name)), name


def test_check_cancel_stops_only_when_asked():
    check_cancel(never, 'pose 3')
    with pytest.raises(Stopped, match='cancelled at pose 3'):
        check_cancel(lambda: True, 'pose 3')


def test_a_capture_averages_the_encoders_at_the_joint_states_rate():
    arm, robot, _ = _ports()
    q = robot.move_joints(SIM.cell.home + 0.1)
    capture = robot.capture(0.2)
    sigma = SIM.noise.encoder_sigma
    assert capture.sample_count == round(0.2 * SIM.joint_states_hz)
    assert np.all(np.abs(capture.q - q) < 5 * sigma / math.sqrt(capture.sample_count))
    assert capture.std == pytest.approx(np.full(len(q), sigma), rel=0.25)
    assert robot.robot_seconds == pytest.approx(0.1 / robot.joint_velocity + 0.2)


def test_a_touch_puts_the_true_tool_tip_on_the_marker():
    arm, robot, _ = _ports()
    robot.touch('P3')
    true_top = frames.apply(SIM.world.T_base_user, SIM.world.marker('P3').true_top)
    error = np.linalg.norm(arm.true_tool()[:3, 3] - true_top)
    assert error < 5 * SIM.noise.touch_sigma + 5 * SIM.repeatability_sigma_at(true_top)
    with pytest.raises(MoveFailed, match="unknown point 'P9'"):
        robot.touch('P9')


def test_a_probe_signal_that_is_not_a_number_is_no_reading():
    """proximity_sensor's rule (the in-process robot used to call it ABOVE_RANGE)."""
    arm, robot, _ = _ports()
    arm.probe_voltage = lambda: math.nan
    with pytest.raises(CaptureFailed, match='INVALID.*not a number'):
        robot.probe()


def test_a_probe_beyond_its_range_reads_above_range():
    arm, robot, _ = _ports()
    robot.move_joints(SIM.cell.home)                 # the probe far above the table
    reading = robot.probe()
    assert reading.status == ReadingStatus.ABOVE_RANGE and math.isnan(reading.distance)


def _measure(method, robot, camera, arm, X, chain_parameters=None, **options):
    model = arm.model
    chain = model.chain(chain_parameters, tool=X)
    return views.measure_frame(
        method, SIM.cell, robot, camera, T_base_user_guess=SIM.world.T_base_user,
        plan_chain=model.chain(tool=SIM.cell.camera.T_flange_optical), chain=chain,
        capture_duration=0.1, max_rms_error=MAX_RMS_ERROR, max_scale_error=MAX_SCALE_ERROR,
        **options)


def test_landmark_multi_measured_on_the_true_robot_finds_the_true_user_frame():
    """The true kinematics and the true hand-eye measure every marker's centre where it lies;
    what is left is the table: the markers' centres are off the nominal plane by its height
    field, which the rigid fit of their centres spreads over the frame."""
    arm, robot, camera = _ports()
    marks = []
    result = _measure('landmark_multi', robot, camera, arm, SIM.camera.T_flange_optical,
                      arm.true_parameters, on_view=lambda i, c, t: marks.append((i, t)))
    assert result, getattr(result, 'message', '')
    distance, angle = frames.transform_error(result.fit.T_base_user, SIM.world.T_base_user)
    print(f'landmark_multi on the true robot: {distance * 1e3:.3f} mm, {angle * 1e3:.3f} mrad')
    assert distance < 0.5e-3 and angle < 2e-3
    markers = sorted(SIM.cell.landmarks.markers)
    assert [i for i, _ in marks] == [m for m in markers for _ in views.VIEW_TILTS]
    assert robot.moves == len(marks) and camera.images >= len(marks)
    assert sorted(result.views) == markers


def test_the_nominal_hand_eye_puts_the_frame_millimetres_off():
    """The same views with the cell's nominal hand-eye (1.6 mm / 8 mrad from the truth): the
    procedure is only as good as the hand-eye it is given."""
    arm, robot, camera = _ports()
    result = _measure('landmark_single', robot, camera, arm, SIM.cell.camera.T_flange_optical,
                      arm.true_parameters)
    assert result
    distance, _ = frames.transform_error(result.fit.T_base_user, SIM.world.T_base_user)
    assert distance > 0.5e-3


def test_a_cancel_stops_at_the_next_view_boundary():
    arm, robot, camera = _ports()
    marks = []
    with pytest.raises(Stopped, match='cancelled at the view of landmark'):
        _measure('landmark_multi', robot, camera, arm, SIM.camera.T_flange_optical,
                 cancelled=lambda: len(marks) >= 2, on_view=lambda i, c, t: marks.append(i))
    assert robot.moves == 2


class _Blind:
    """A camera that sends no images."""

    def now_ns(self) -> int:
        return 0

    def landmarks_after(self, t_ns, wanted, max_images, timeout):
        raise CaptureFailed('no image within 5 s; is the camera up?')


def test_a_view_without_images_is_a_capture_failure_naming_the_landmark():
    arm, robot, _ = _ports()
    result = _measure('landmark_single', robot, _Blind(), arm, SIM.camera.T_flange_optical)
    first = min(SIM.cell.landmarks.markers)
    assert not result and result.code == ErrorCode.CAPTURE_FAILED and not result.p_base.size
    assert result.message == (f'landmark_single: view of landmark {first}: no image within 5 s;'
                              ' is the camera up?')


def test_a_cell_without_a_camera_is_refused_before_moving():
    from dataclasses import replace
    arm, robot, camera = _ports()
    result = views.measure_frame(
        'landmark_multi', replace(SIM.cell, camera=None), robot, camera,
        T_base_user_guess=SIM.world.T_base_user, plan_chain=arm.model.chain(),
        chain=arm.model.chain(), capture_duration=0.1, max_rms_error=1e-3,
        max_scale_error=1e-2)
    assert not result and result.code == ErrorCode.INVALID_INPUT
    assert 'add camera:' in result.message and robot.moves == 0


def test_the_camera_sees_the_board_when_asked():
    arm, robot, camera = _ports(boards=True)
    T_base_user = SIM.world.T_base_user
    plan = kinematics.model_for(SIM.cell)
    from cobot_calib_ros.core.landmarks.hand_eye import hand_eye_views
    q = hand_eye_views(SIM.cell, plan, 3, 0, T_base_user=T_base_user)[0]
    robot.move_joints(q)
    t = camera.now_ns()
    image = camera.landmarks_after(t, lambda im: im.find('board') is not None, 3, 5.0)
    board = image.find('board')
    assert image.stamp_ns > t and board is not None
    truth = SimCamera(SIM, arm).T_optical_targets(arm.q)['board', board.id]
    distance, angle = frames.transform_error(board.T_optical_target, truth)
    assert distance < 1e-3 and angle < 5e-3
