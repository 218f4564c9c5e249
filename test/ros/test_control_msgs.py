"""control_msgs/action/FollowJointTrajectory as on ROS 2 Jazzy (interfaces/control_msgs).

A ros2_control joint_trajectory_controller on Jazzy serves this action; a client whose type
hash differs does not match it on hash-checking RMWs (Zenoh). The hashes below are the ones
rosidl_generator_c wrote into a public colcon build of control_msgs 5.0.0 (the Jazzy series:
jazzy branch 5.x; the three definitions have not changed since 2021):
github.com/saahu27/aprs, commit 4013b140da197a3dda08b2b4089a2ff77d0627c9,
aprs_ws/build/control_msgs/rosidl_generator_c/control_msgs/action/detail/
follow_joint_trajectory__description.c (..._get_type_hash) and
aprs_ws/install/control_msgs/share/control_msgs/msg/JointComponentTolerance.json.
"""
import importlib
import json
from pathlib import Path

from control_msgs.action import FollowJointTrajectory
from control_msgs.msg import JointComponentTolerance, JointTolerance
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import JointTrajectoryPoint

JAZZY = {
    'control_msgs/action/FollowJointTrajectory':
        'RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6',
    'control_msgs/action/FollowJointTrajectory_Goal':
        'RIHS01_8a9060704b269608f5a340934cc26e66869dd14bdac29e2e7fd9ec8b9882d205',
    'control_msgs/action/FollowJointTrajectory_Result':
        'RIHS01_8002e99ed2c14c6faa522f2a93c26d744c5982f254f9e98ff9c6f19789bdb220',
    'control_msgs/action/FollowJointTrajectory_Feedback':
        'RIHS01_3fd0aaecf71725121ae1ff7f01098a5e0da581e672be18a6b2c286cb43d96b49',
    'control_msgs/action/FollowJointTrajectory_SendGoal':
        'RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f',
    'control_msgs/msg/JointComponentTolerance':
        'RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4',
    # a public rosidl_generator_c joint_tolerance__struct.h (control_msgs__msg__JointTolerance__
    # TYPE_HASH), found by exact-string search; the Goal's hash above covers it as well
    'control_msgs/msg/JointTolerance':
        'RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648',
}


def _generated_hashes(kind: str, name: str) -> dict[str, str]:
    """Every hash rosidl_generator_type_description wrote in <prefix>/share/control_msgs/
    <kind>/<name>.json, <prefix> being where control_msgs was imported from."""
    module = Path(importlib.import_module('control_msgs').__file__).resolve()
    path = next(p / 'share' / 'control_msgs' / kind / f'{name}.json' for p in module.parents
                if (p / 'share' / 'control_msgs' / 'package.xml').is_file())
    hashes = json.loads(path.read_text())['type_hashes']
    return {h['type_name']: h['hash_string'] for h in hashes}


@pytest.mark.parametrize('type_name', sorted(JAZZY))
def test_type_hash_is_jazzy(type_name):
    hashes = {**_generated_hashes('action', 'FollowJointTrajectory'),
              **_generated_hashes('msg', 'JointComponentTolerance'),
              **_generated_hashes('msg', 'JointTolerance')}
    assert hashes[type_name] == JAZZY[type_name]


def test_joint_tolerance_fields_in_jazzy_order():
    assert list(JointTolerance.get_fields_and_field_types()) == [
        'name', 'position', 'velocity', 'acceleration']
    assert JointComponentTolerance.ROTATION == 5


def test_error_codes_and_a_goal_round_trip():
    R = FollowJointTrajectory.Result
    assert (R.SUCCESSFUL, R.INVALID_GOAL, R.INVALID_JOINTS, R.OLD_HEADER_TIMESTAMP,
            R.PATH_TOLERANCE_VIOLATED, R.GOAL_TOLERANCE_VIOLATED) == (0, -1, -2, -3, -4, -5)
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ['lbr_A1', 'lbr_A2']
    goal.trajectory.points = [JointTrajectoryPoint(positions=[0.1, -0.2])]
    goal.goal_tolerance = [JointTolerance(name='lbr_A1', position=0.01)]
    back = deserialize_message(serialize_message(goal), FollowJointTrajectory.Goal)
    assert back == goal
