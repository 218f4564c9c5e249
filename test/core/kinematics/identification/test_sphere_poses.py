"""Algorithm 2 pose grid: targets reached, arm angle via the locked joint, unreachable skipped."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics import fk
from cobot_calib_ros.core.kinematics.identification import (
    lock_joint, sphere_pose_grid, tool_transform)
from cobot_calib_ros.core.kinematics.model import ur10_pybotics
from sphere_scene import approach, CENTRES_BASE, home_for, MODEL, TOOL

CHAIN = MODEL.chain(None, tool_transform(TOOL))


def test_lock_joint_keeps_forward_kinematics():
    rng = np.random.default_rng(0)
    q = rng.uniform(0.9 * CHAIN.lower, 0.9 * CHAIN.upper, (20, 7))
    for index in (0, 2, 6):
        sub = lock_joint(CHAIN, index, 0.7)
        q_full = q.copy()
        q_full[:, index] = 0.7
        assert sub.dof == 6
        assert fk(sub, np.delete(q_full, index, axis=1)) == pytest.approx(fk(CHAIN, q_full),
                                                                          abs=1e-12)


def test_grid_reaches_every_target_with_the_arm_angle_on_joint_a3():
    centre = CENTRES_BASE[2]
    R = approach(CHAIN, centre)
    home = home_for(CHAIN, centre, R)
    angles, arms = (-20.0, 0.0, 20.0), (-20.0, 10.0)
    grid = sphere_pose_grid(CHAIN, centre, R, home, angles, arms)
    assert len(grid) == 27 * 2 and not grid.unreachable
    q = np.array([p.q for p in grid])
    T = fk(CHAIN, q)
    for pose, T_reached in zip(grid, T):
        expected = R @ frames.rot_x(math.radians(pose.rx_deg)) \
            @ frames.rot_y(math.radians(pose.ry_deg)) @ frames.rot_z(math.radians(pose.rz_deg))
        assert pose.T_base_tool[:3, :3] == pytest.approx(expected, abs=1e-12)
        assert pose.T_base_tool[:3, 3] == pytest.approx(centre, abs=0.0)
        assert T_reached == pytest.approx(pose.T_base_tool, abs=1e-9)
        assert pose.q[2] == pytest.approx(home[2] + math.radians(pose.arm_deg), abs=1e-15)
    assert np.all(q >= CHAIN.lower) and np.all(q <= CHAIN.upper)
    assert [(p.rx_deg, p.ry_deg, p.rz_deg, p.arm_deg) for p in grid[:2]] == [
        (-20.0, -20.0, -20.0, -20.0), (-20.0, -20.0, 0.0, -20.0)]


def test_unreachable_poses_are_skipped_and_reported():
    """A sphere 1.2 m out is beyond the iiwa7's reach; a locked joint beyond its limit too."""
    R = approach(CHAIN, CENTRES_BASE[0])
    home = home_for(CHAIN, CENTRES_BASE[0], R)
    far = sphere_pose_grid(CHAIN, [1.2, 0.0, 0.2], R, home, (0.0,), (0.0,))
    assert len(far) == 0 and len(far.unreachable) == 1
    assert 'no convergence' in far.unreachable[0].message
    home_at_limit = home.copy()
    home_at_limit[2] = CHAIN.upper[2] - math.radians(5.0)
    grid = sphere_pose_grid(CHAIN, CENTRES_BASE[0], R, home_at_limit, (0.0,), (0.0, 10.0))
    beyond = [u for u in grid.unreachable if u.arm_deg == 10.0]
    assert len(beyond) == 1 and 'beyond limits' in beyond[0].message
    assert all(p.arm_deg == 0.0 for p in grid)


def test_six_joint_robot_has_no_arm_angle():
    model = ur10_pybotics()
    chain = model.chain(None, tool_transform([0.0, 0.05, 0.1]))
    home = np.array([0.0, -1.9, 1.9, -1.57, -1.57, 0.0])
    T_home = fk(chain, home)
    grid = sphere_pose_grid(chain, T_home[:3, 3], T_home[:3, :3], home, (-10.0, 10.0),
                            (-20.0, 0.0, 20.0))
    assert len(grid) + len(grid.unreachable) == 8
    assert len(grid) == 8 and {p.arm_deg for p in grid} == {0.0}
    assert fk(chain, np.array([p.q for p in grid])) == pytest.approx(
        np.array([p.T_base_tool for p in grid]), abs=1e-9)
    with pytest.raises(ValueError, match='6- or 7-joint'):
        sphere_pose_grid(chain, T_home[:3, 3], T_home[:3, :3], home[:5])
