"""core.driver: the presets file, a move's timing, the settle criterion, FollowJointTrajectory
error codes as failures."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from cobot_calib_ros.core.driver import (joint_order, move_seconds, not_settled, parse_presets,
                                         SettleWatch, trajectory_failure)
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.kinematics import model_by_name

PRESETS = Path(__file__).resolve().parents[2] / 'config' / 'driver_presets.yaml'


@pytest.fixture(scope='module')
def presets():
    presets = parse_presets(yaml.safe_load(PRESETS.read_text()))
    assert not isinstance(presets, Failure), presets
    return presets


def test_shipped_presets_name_the_real_drivers_actions(presets):
    assert presets['ur'].action == '/scaled_joint_trajectory_controller/follow_joint_trajectory'
    assert presets['lbr'].action == '/lbr/joint_trajectory_controller/follow_joint_trajectory'
    assert presets['lbr'].joint_names == tuple(f'lbr_A{i}' for i in range(1, 8))
    assert presets['franka'].action == '/fr3_arm_controller/follow_joint_trajectory'
    assert presets['franka'].joint_names[-1] == 'fr3_joint7'
    assert len(presets['ur'].joint_names) == 6
    assert presets['mock'].joint_names == () and presets['mock'].compliant_action


def test_lbr_preset_maps_onto_the_iiwa_model_in_any_message_order(presets):
    model = model_by_name('iiwa7')
    names = list(reversed(presets['lbr'].joint_names))     # a driver may list them any order
    order = joint_order(presets['lbr'].joint_names, model.joint_names, names)
    positions = np.arange(7.0)[::-1]                       # position of lbr_Ai is i - 1
    assert positions[order].tolist() == [0, 1, 2, 3, 4, 5, 6]


def test_a_preset_for_another_arm_is_refused_with_the_joint_counts(presets):
    model = model_by_name('iiwa7')
    wrong = joint_order(presets['ur'].joint_names, model.joint_names, [])
    assert isinstance(wrong, Failure) and wrong.code == ErrorCode.INVALID_INPUT
    assert '6 joints' in wrong.message and 'has 7' in wrong.message
    missing = joint_order(presets['lbr'].joint_names, model.joint_names, ['lbr_A1'])
    assert missing.code == ErrorCode.NO_DATA and 'lbr_A2' in missing.message


@pytest.mark.parametrize('entry, words', [
    ({'action': ''}, 'action'),
    ({'action': 'a', 'joint_names': ['j', 'j']}, 'distinct'),
    ({'action': 'a', 'velocity_scaling': 1.5}, 'velocity_scaling'),
    ({'action': 'a', 'speed': 1}, 'unknown keys'),
])
def test_a_bad_preset_says_which_key(presets, entry, words):
    good = {k: getattr(presets['mock'], k) for k in (
        'max_joint_velocity', 'velocity_scaling', 'settle_speed', 'settle_window',
        'settle_timeout', 'goal_time_tolerance')}
    result = parse_presets({'x': {**good, **entry}})
    assert isinstance(result, Failure) and words in result.message and "'x'" in result.message


def test_move_seconds_is_the_largest_step_at_the_scaled_speed(presets):
    ur = presets['ur']        # 1.0 rad/s * 0.3
    assert ur.move_seconds([0, 0], [0.3, -0.6], 0.0) == pytest.approx(2.0)
    assert ur.move_seconds([0, 0], [0.3, -0.6], 0.5) == pytest.approx(4.0)
    assert ur.move_seconds([0, 0], [0.3, -0.6], 1e-6) == pytest.approx(200.0)   # 1 % at least


def test_move_seconds_times_a_stack_of_targets_each():
    """As the pose planner times its candidates: one duration per row."""
    targets = np.array([[0.5, 0.1], [-0.2, 0.4], [0.0, 0.0]])
    assert move_seconds([0.1, 0.0], targets, 2.0).tolist() == pytest.approx([0.2, 0.2, 0.05])
    assert move_seconds([0.1, 0.0], targets, 2.0, 0.5).tolist() == pytest.approx(
        [0.4, 0.4, 0.1])


def test_settle_needs_a_whole_quiet_window():
    watch = SettleWatch(speed=0.01, window=0.1)    # at most 1 mrad of spread in 0.1 s
    rng = np.random.default_rng(1)
    t = np.arange(0, 0.3, 0.001)
    for ti in t[:50]:
        watch.add(ti, [0.0 + rng.normal(0, 2e-6)])
    assert not watch.settled()                      # 0.05 s: the window is not covered yet
    for ti in t[50:]:
        watch.add(ti, [0.0 + rng.normal(0, 2e-6)])
    assert watch.settled() and watch.worst()[0] < 0.001   # encoder noise: 1e-5 rad / 0.1 s


def test_ringing_never_settles_and_the_failure_names_the_joint():
    watch = SettleWatch(speed=0.01, window=0.1)
    for ti in np.arange(0, 1.0, 0.001):            # 2 mrad amplitude at 8 Hz on the 2nd joint
        watch.add(ti, [0.0, 0.002 * np.sin(2 * np.pi * 8 * ti)])
    speed, joint = watch.worst()
    assert joint == 1 and speed == pytest.approx(0.04, rel=0.05)   # 4 mrad peak to peak / 0.1
    failure = not_settled(watch, ('j1', 'j2'), 5.0)
    assert failure.code == ErrorCode.MOVING
    assert 'j2 still moved 0.04' in failure.message and 'within 5.0 s' in failure.message


@pytest.mark.parametrize('code, name, cause', [
    (-1, 'INVALID_GOAL', ErrorCode.INVALID_INPUT), (-2, 'INVALID_JOINTS', ErrorCode.INVALID_INPUT),
    (-3, 'OLD_HEADER_TIMESTAMP', ErrorCode.MOTION_FAILED),
    (-4, 'PATH_TOLERANCE_VIOLATED', ErrorCode.MOTION_FAILED),
    (-5, 'GOAL_TOLERANCE_VIOLATED', ErrorCode.MOTION_FAILED),
    (-99, 'error_code -99', ErrorCode.MOTION_FAILED)])
def test_every_follow_joint_trajectory_error_code_has_a_message(code, name, cause):
    failure = trajectory_failure('/jtc/follow_joint_trajectory', code, 'joint a6 off by 0.2')
    assert failure.code == cause
    assert failure.message.startswith(f'/jtc/follow_joint_trajectory aborted the move ({name}: '
                                      'joint a6 off by 0.2); ')
