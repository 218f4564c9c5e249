"""Compensated motion (issue 29.1): a pose target in the base or a user frame, for a named tool,
solved with the active kinematic calibration, sent to ``move_to`` as joints.

The controller behind ``move_to`` (mock_robot, a vendor's) solves a pose with its own nominal
model; so the suite solves it here with the calibrated one (core.rig) and commands the joints
(MoveTo TARGET_JOINTS): the tool ends up where the calibrated model says, whichever node
serves move_to. ``kinematics: nominal`` solves with the nominal model the same way.
"""
from __future__ import annotations

from dataclasses import dataclass
import json
from pathlib import Path
from typing import Any

import numpy as np

from cobot_calib_ros.core import rig
from cobot_calib_ros.core.kinematics.program_filter import out_of_reach
from cobot_calib_ros.store.kinematics import unseen_tool_note
from cobot_calib_ros.store.rigs import active_hand_eye

ACTIVE = ('active', 'latest')
NOMINAL = 'nominal'
JOINTS_TIMEOUT = 10.0    # [s] for a joint_states message (the IK seed)


def kinematic_record(repo, model, choice: str, allow_nominal: bool = True
                     ) -> dict[str, Any] | None:
    """The kinematic calibration record ``choice`` names: 'active' (the robot's active one;
    None: nominal when it has none and ``allow_nominal``), 'nominal' (None), an id, or an
    <id>.json file. ValueError saying what to do."""
    if choice.endswith('.json'):
        try:
            return json.loads(Path(choice).expanduser().read_text(encoding='utf-8'))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f'--kinematics {choice}: cannot read a calibration record '
                             f'({exc})') from None
    if choice == NOMINAL and allow_nominal:
        return None
    try:
        record = repo.kinematics.resolve('latest' if choice in ACTIVE else choice, model.name)
    except KeyError as exc:
        raise ValueError(f'--kinematics: {exc.args[0]}') from None
    if record is None and not allow_nominal:
        raise ValueError(f'no active kinematic calibration of the {model.name} in {repo.root}; '
                         'identify one first, or give --kinematics ID or FILE.json')
    return record


def user_frame(repo, frame_id: str = '') -> tuple[np.ndarray, str]:
    """(T_base_user, its id): the user frame ``frame_id`` of the repository's cell, else its
    active one. ValueError saying what to do."""
    record = repo.user_frames.get(frame_id) if frame_id else repo.user_frames.active()
    if record is None:
        raise ValueError(f'no user frame {frame_id!r} in the results of cell {repo.cell}; list '
                         'them with `cobot-calib history`' if frame_id else
                         f'no active user frame in the results of cell {repo.cell}; calibrate '
                         'one first (cobot-calib teach), or give --frame base')
    return np.array(record['result']['T_base_user'], dtype=float), record['id']


@dataclass(frozen=True)
class Solved:
    """A resolved target: joints for move_to and what they were solved with."""

    q: np.ndarray             # (n,) [rad]
    T_base_tool: np.ndarray   # (4, 4) the target in the base frame
    kinematics: str           # the calibration's id, or 'nominal'
    user_frame: str           # the user frame's id, '' for the base
    note: str = ''            # what the calibration could not see that the tool carries


def solve(cell, repo, T_frame_tool: np.ndarray, seed: np.ndarray, *, frame: str = 'base',
          frame_id: str = '', tool: str = 'tcp', kinematics: str = 'active') -> Solved:
    """The joints that put ``tool`` at ``T_frame_tool`` (in the base, or in the user frame
    ``frame_id`` / the active one for ``frame`` 'user') on the ``kinematics`` model, from
    ``seed``. ValueError saying what to do when a choice cannot be met or the target cannot
    be reached."""
    from cobot_calib_ros.core.kinematics import model_for
    model = model_for(cell)
    record = kinematic_record(repo, model, kinematics)
    chain = rig.Rig(cell, rig.ActiveSet(record, active_hand_eye(repo)), model).chain(tool)
    T_base_frame, frame_label = (user_frame(repo, frame_id) if frame == 'user'
                                 else (np.eye(4), ''))
    result = rig.solve_target(chain, T_frame_tool, seed, cell.home, T_base_frame)
    label = NOMINAL if record is None else record['id']
    T_base_tool = T_base_frame @ np.asarray(T_frame_tool, float)
    if not result:
        raise ValueError(f'the target cannot be reached by the {label} model: '
                         f'{out_of_reach(chain, T_base_tool[:3, 3]) or result.message}')
    return Solved(result.q, T_base_tool, label, frame_label, unseen_tool_note(record))


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
    from cobot_calib_ros.ros.action_client import ActionClient
    from cobot_calib_ros.ros.calls import run_action
    client = ActionClient(node, MoveTo, 'move_to')
    try:
        goal = MoveTo.Goal(target_type=MoveTo.Goal.TARGET_JOINTS,
                           positions=[float(v) for v in q], speed_scale=float(speed_scale))
        return run_action(node, client, goal, timeout, executor=executor)[1]
    finally:
        client.destroy()
