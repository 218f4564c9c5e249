"""Compensated motion (issue 29.1): a pose target in the base or a user frame, for a named tool,
solved with the active kinematic calibration, sent to ``move_to`` as joints.

The controller behind ``move_to`` (mock_robot, a vendor's) solves a pose with its own nominal
model; so the suite solves it here with the calibrated one (core.rig) and commands the joints
(MoveTo TARGET_JOINTS): the tool ends up where the calibrated model says, whichever node
serves move_to. ``kinematics: nominal`` solves with the nominal model the same way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cobot_calib_ros.core import rig
from cobot_calib_ros.core.kinematics.program_filter import out_of_reach
from cobot_calib_ros.store.rigs import active_set

JOINTS_TIMEOUT = 10.0    # [s] for a joint_states message (the IK seed)


@dataclass(frozen=True)
class Solved:
    """A resolved target: joints for move_to and what they were solved with."""

    q: np.ndarray             # (n,) [rad]
    T_base_tool: np.ndarray   # (4, 4) the target in the base frame
    kinematics: str           # the calibration's id, or 'nominal'
    user_frame: str           # the user frame's id, '' for the base
    tool_record: str = ''     # the result the tool came from: a TCP or hand-eye id, 'nominal'
    stale: tuple = ()         # core.provenance.Stale of the results used
    note: str = ''            # what the calibration could not see that the tool carries

    def summary(self) -> dict:
        """What the JSON of move says about the results used."""
        return {'kinematics': self.kinematics, 'tool_record': self.tool_record,
                'stale': [s.to_dict() for s in self.stale]}


def solve(cell, repo, T_frame_tool: np.ndarray, seed: np.ndarray, *, frame: str = 'base',
          frame_id: str = '', tool: str = 'tcp', kinematics: str = 'active') -> Solved:
    """The joints that put ``tool`` at ``T_frame_tool`` (in the base, or in the user frame
    ``frame_id`` / the active one for ``frame`` 'user') on the ``kinematics`` model with the
    cell's active set (store.rigs.active_set: the active TCP, hand-eye), from ``seed``.
    ValueError saying what to do when a choice cannot be met or the target cannot be
    reached."""
    from cobot_calib_ros.core.kinematics import model_for
    model = model_for(cell)
    active = active_set(repo, cell, kinematics, frame_id if frame == 'user' else '', model)
    the_rig = rig.Rig(cell, active, model)
    chain = the_rig.chain(tool)
    if frame == 'user':
        if active.user_frame is None:
            raise ValueError(f'no active user frame in the results of cell {repo.cell}; '
                             'calibrate one first (cobot-calib teach), or give --frame base')
        T_base_frame, frame_label = the_rig.T_base_user(), active.user_frame.id
    else:
        T_base_frame, frame_label = np.eye(4), ''
    result = rig.solve_target(chain, T_frame_tool, seed, cell.home, T_base_frame)
    label = active.kinematics_label
    T_base_tool = T_base_frame @ np.asarray(T_frame_tool, float)
    if not result:
        far = out_of_reach(chain, T_base_tool[:3, 3])
        raise ValueError(f'the target cannot be reached by the {label} model: '
                         f'{(result if far is None else far).message}')
    note = active.kinematics.unseen_tool_note if active.kinematics is not None else ''
    return Solved(result.q, T_base_tool, label, frame_label, active.tool_label(tool),
                  active.stale_used(tool, frame == 'user'), note)


def suite_cell(node) -> str:
    """The cell file the running suite's user_frame_solver was started with, else the default
    cell."""
    from cobot_calib_ros.paths import DEFAULT_CELL
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.ros.remote_params import read_parameter
    try:
        return read_parameter(node, 'user_frame_solver', 'cell_file', 10.0) or DEFAULT_CELL
    except CallError:
        return DEFAULT_CELL


def current_joints(node, joint_names, executor=None,
                   timeout: float = JOINTS_TIMEOUT) -> np.ndarray:
    """The arm's joints [rad] from one joint_states message, in ``joint_names`` order;
    CallError when none comes."""
    from sensor_msgs.msg import JointState
    from cobot_calib_ros.ros import qos
    from cobot_calib_ros.ros.calls import CallError, spin_until
    got = []
    subscription = node.create_subscription(JointState, 'joint_states', got.append,
                                            qos.JOINT_STATES)
    try:
        if not spin_until(node, lambda: bool(got), timeout, executor):
            raise CallError(f'no joint_states within {timeout:.0f} s; is the node suite up?')
    finally:
        node.destroy_subscription(subscription)
    joints = dict(zip(got[-1].name, got[-1].position))
    missing = [n for n in joint_names if n not in joints]
    if missing:
        raise CallError(f'joint_states lack {missing}; is this suite of another robot?')
    return np.array([joints[n] for n in joint_names])


def move_joints(node, q: np.ndarray, speed_scale: float = 0.0, executor=None,
                timeout: float = 120.0):
    """Send q [rad] to move_to (TARGET_JOINTS) and wait: its MoveTo result; CallError when
    the action is not there or does not finish."""
    from cobot_calib_msgs.action import MoveTo
    from cobot_calib_ros.ros.calls import run_action_once
    goal = MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS,
                       positions=[float(v) for v in q], speed_scale=float(speed_scale))
    return run_action_once(node, MoveTo, 'move_to', goal, timeout, executor=executor)
