"""Driving a ros2_control arm: driver presets, one move's timing, the settle criterion, and what
each control_msgs/FollowJointTrajectory error code means (as a core.errors.Failure).

A real arm on ROS 2 is a joint_trajectory_controller (FollowJointTrajectory) plus a
joint_state_broadcaster (/joint_states). ``nodes.robot_adapter`` turns the suite's ``move_to``
into trajectory goals with what this module decides; it holds no ROS types. SI units: joints
[rad], speeds [rad/s], times [s].
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure

Array = NDArray[np.float64]
STAMP_SLACK = 1e-6    # [s] stamps this close count as one time (float sums of periods)

PRESET_KEYS = ('action', 'joint_names', 'max_joint_velocity', 'velocity_scaling',
               'settle_speed', 'settle_window', 'settle_timeout', 'goal_time_tolerance',
               'compliant_action', 'notes')


@dataclass(frozen=True)
class DriverPreset:
    """How to drive one kind of ros2_control arm (config/driver_presets.yaml)."""

    name: str
    action: str                   # FollowJointTrajectory action of its trajectory controller
    joint_names: tuple[str, ...]  # the driver's joint names, in the kinematic model's order
    max_joint_velocity: float     # [rad/s] the joint speed of a move at velocity scaling 1
    velocity_scaling: float       # (0, 1] of max_joint_velocity at the suite's speed_scale 1
    settle_speed: float           # [rad/s] settled: every joint slower than this ...
    settle_window: float          # [s] ... over a window this long of /joint_states
    settle_timeout: float         # [s] after the trajectory's end: never settled = a failure
    goal_time_tolerance: float    # [s] the controller's leeway past the trajectory's end
    compliant_action: str = ''    # a FollowJointTrajectory under impedance control; '' = none
    notes: str = ''

    def move_seconds(self, q_from: ArrayLike, q_to: ArrayLike, speed_scale: float) -> float:
        """The trajectory's duration [s] (:func:`move_seconds` at this arm's joint speed)."""
        return float(move_seconds(q_from, q_to,
                                  self.max_joint_velocity * self.velocity_scaling, speed_scale))


def move_seconds(q_from: ArrayLike, q_to: ArrayLike, joint_speed: float,
                 speed_scale: float = 1.0):
    """A joint-space move's duration [s]: the largest joint step at ``joint_speed`` [rad/s]
    times ``speed_scale`` (0 = 1, clipped to [0.01, 1]). Every robot here times a move this
    way: the ros2_control driver, mock_robot, the sim's DirectRobot and the pose planner.
    ``q_to`` may be a stack of targets (a time for each)."""
    scale = min(max(speed_scale or 1.0, 0.01), 1.0)
    step = np.abs(np.asarray(q_to, float) - np.asarray(q_from, float)).max(axis=-1)
    return step / (joint_speed * scale)


def parse_presets(data: Any) -> dict[str, DriverPreset] | Failure:
    """The presets of a driver_presets YAML document ({name: {key: value}}), or what is wrong."""
    if not isinstance(data, Mapping) or not data:
        return Failure(ErrorCode.INVALID_INPUT, 'driver presets: expected a mapping of preset '
                       'names to {action, joint_names, ...}')
    presets = {}
    for name, entry in data.items():
        preset = _preset(str(name), entry)
        if isinstance(preset, Failure):
            return preset
        presets[preset.name] = preset
    return presets


def _preset(name: str, entry: Any) -> DriverPreset | Failure:
    def bad(what: str) -> Failure:
        return Failure(ErrorCode.INVALID_INPUT, f'driver preset {name!r}: {what}')
    if not isinstance(entry, Mapping):
        return bad('expected a mapping')
    unknown = sorted(set(entry) - set(PRESET_KEYS))
    if unknown:
        return bad(f'unknown keys {unknown}; known: {", ".join(PRESET_KEYS)}')
    if not isinstance(entry.get('action'), str) or not entry['action'].strip('/'):
        return bad('action: the FollowJointTrajectory action name is required')
    names = entry.get('joint_names', [])
    if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names) \
            or len(set(names)) != len(names):
        return bad('joint_names: a list of distinct joint names (empty: the model\'s)')
    numbers = {}
    for key, low, high in (('max_joint_velocity', 0.0, 10.0), ('velocity_scaling', 0.0, 1.0),
                           ('settle_speed', 0.0, 1.0), ('settle_window', 0.0, 10.0),
                           ('settle_timeout', 0.0, 600.0), ('goal_time_tolerance', 0.0, 60.0)):
        value = entry.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value) or not low < value <= high:
            return bad(f'{key}: a number in ({low:g}, {high:g}] is required, got {value!r}')
        numbers[key] = float(value)
    return DriverPreset(name, entry['action'], tuple(names), **numbers,
                        compliant_action=str(entry.get('compliant_action') or ''),
                        notes=str(entry.get('notes') or ''))


def joint_order(preset_names: tuple[str, ...], model_names: tuple[str, ...],
                message_names: list[str]) -> Array | Failure:
    """Indices into a /joint_states message's arrays that give the model's joint order.

    ``preset_names`` are the driver's names of the model's joints (empty: the model's own)."""
    wanted = preset_names or model_names
    if len(wanted) != len(model_names):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'the driver preset names {len(wanted)} joints, the robot model has '
                       f'{len(model_names)} ({", ".join(model_names)}); pick the preset of '
                       'this robot or set its joint_names')
    where = {n: i for i, n in enumerate(message_names)}
    missing = [n for n in wanted if n not in where]
    if missing:
        return Failure(ErrorCode.NO_DATA,
                       f'/joint_states has no {", ".join(missing)} (it has '
                       f'{", ".join(message_names) or "no joints"}); set the preset\'s '
                       'joint_names to the driver\'s')
    return np.array([where[n] for n in wanted], dtype=int)


class SettleWatch:
    """Whether the arm has come to rest: over the last ``window`` s of joint readings, every
    joint moved by at most ``speed * window`` (max - min: ringing counts, not only drift).

    Encoder noise counts as motion too, so ``speed * window`` must stay well above the
    encoders' noise (the mock's 2e-5 rad against 0.005 rad/s * 0.1 s = 5e-4 rad)."""

    def __init__(self, speed: float, window: float) -> None:
        self.speed, self.window = speed, window
        self._samples: deque[tuple[float, Array]] = deque()

    def clear(self) -> None:
        self._samples.clear()

    def add(self, t: float, q: ArrayLike) -> None:
        """One reading at time ``t`` [s] (the message stamp) of joints ``q`` [rad]."""
        self._samples.append((t, np.asarray(q, dtype=float)))
        while len(self._samples) > 2 and self._samples[1][0] <= t - self.window:
            self._samples.popleft()

    def worst(self) -> tuple[float, int]:
        """(speed [rad/s], joint index) of the joint that moved most over the window: its
        range divided by the window; (inf, -1) until the readings span the window."""
        if len(self._samples) < 2 or \
                self._samples[-1][0] - self._samples[0][0] < self.window - STAMP_SLACK:
            return math.inf, -1
        q = np.array([s[1] for s in self._samples])
        spread = q.max(axis=0) - q.min(axis=0)
        j = int(np.argmax(spread))
        return float(spread[j]) / self.window, j

    def settled(self) -> bool:
        return self.worst()[0] <= self.speed


def not_settled(watch: SettleWatch, joint_names: tuple[str, ...], waited: float) -> Failure:
    """The failure of an arm still moving ``waited`` s after its trajectory ended."""
    speed, j = watch.worst()
    if j < 0:
        what = 'no /joint_states came to judge it by'
    else:
        what = (f'{joint_names[j]} still moved {speed:.4f} rad/s over the last '
                f'{watch.window:g} s (settled: below {watch.speed:g} rad/s)')
    return Failure(ErrorCode.MOVING,
                   f'the arm did not settle within {waited:.1f} s after the move: {what}; '
                   'nothing was captured. Check the controller gains (a ringing arm), the '
                   'brakes, or raise settle_speed / settle_timeout in the driver preset')


# control_msgs/action/FollowJointTrajectory Result.error_code: name, what to check
_FJT_CODES = {
    -1: ('INVALID_GOAL', 'the controller refused the trajectory (joint limits, an empty or '
         'ill-timed trajectory); check that the target is within the limits and that the '
         'trajectory controller is active'),
    -2: ('INVALID_JOINTS', 'the trajectory\'s joints are not the controller\'s; set the driver '
         'preset\'s joint_names (config/driver_presets.yaml) to the controller\'s joints'),
    -3: ('OLD_HEADER_TIMESTAMP', 'the trajectory\'s start time had already passed; check that '
         'robot_adapter and the driver share a clock (use_sim_time on both or neither)'),
    -4: ('PATH_TOLERANCE_VIOLATED', 'the arm left the path tolerance during the move (a '
         'collision, a protective stop, or too fast for the controller); check the arm, then '
         'lower velocity_scaling'),
    -5: ('GOAL_TOLERANCE_VIOLATED', 'the arm did not reach the target within the goal tolerance '
         'in time; check the controller gains, or raise goal_time_tolerance'),
}


def trajectory_failure(action: str, error_code: int, error_string: str) -> Failure:
    """The failure a FollowJointTrajectory result with ``error_code`` != 0 means."""
    name, advice = _FJT_CODES.get(error_code, (f'error_code {error_code}',
                                               'see the driver\'s log'))
    detail = f': {error_string}' if error_string else ''
    code = ErrorCode.INVALID_INPUT if error_code in (-1, -2) else ErrorCode.MOTION_FAILED
    return Failure(code, f'{action} aborted the move ({name}{detail}); {advice}')


def rejected(action: str) -> Failure:
    """The failure of a trajectory goal the controller did not accept."""
    return Failure(ErrorCode.MOTION_FAILED,
                   f'{action} rejected the trajectory goal; is the trajectory controller active '
                   '(UR: is the External Control program running on the pendant)?')


def aborted_without_code(action: str, status: str) -> Failure:
    """The failure of a goal that ended ``status`` (ABORTED, CANCELED by the driver) with
    error_code SUCCESSFUL."""
    return Failure(ErrorCode.MOTION_FAILED,
                   f'{action} ended the move {status} without an error code (a driver stop, '
                   'an e-stop or another client preempting it); check the robot, then retry')
