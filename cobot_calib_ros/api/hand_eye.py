"""Client side of the hand-eye calibration (hand_eye_calibrator's ``calibrate_hand_eye``).

:func:`calibrate_hand_eye` sends the goal and waits; :func:`error_against_truth` compares a
hand-eye with the mock robot's ground truth (simulation only: a real cell has none). Used by
``cobot-calib hand-eye`` and by ``cobot-calib experiment user-frame`` before its landmark rows.
"""
from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from cobot_calib_ros.ros.calls import call_service, CallError, run_action
from cobot_calib_ros.core import frames

HAND_EYE_TIMEOUT = 600.0    # [s] for the whole calibration (12 views take 5-60 s here)


@dataclass(frozen=True)
class HandEyeError:
    """How far a hand-eye is from the truth: the optical frame's origin [m] and its rotation
    [rad]; the same for the cell's nominal hand-eye."""

    position_m: float
    rotation_rad: float
    nominal_position_m: float
    nominal_rotation_rad: float


def calibrate_hand_eye(node, views: int = 0, timeout: float = HAND_EYE_TIMEOUT,
                       feedback=None, executor=None):
    """Run calibrate_hand_eye to its end; the result (CallError if the action is missing or
    does not finish in time; a failed calibration comes back with its error_code)."""
    from cobot_calib_msgs.action import CalibrateHandEye
    from cobot_calib_ros.ros.action_client import ActionClient
    client = ActionClient(node, CalibrateHandEye, 'calibrate_hand_eye')
    try:
        _, result = run_action(node, client, CalibrateHandEye.Goal(views=views), timeout,
                               feedback, executor)
    finally:
        client.destroy()
    return result


def error_against_truth(node, T_flange_optical: np.ndarray, nominal: np.ndarray,
                        executor=None) -> HandEyeError:
    """The hand-eye's error (and the nominal one's) against the mock robot's truth
    (get_ground_truth)."""
    from cobot_calib_msgs.srv import GetGroundTruth
    from cobot_calib_ros.ros import convert
    client = node.create_client(GetGroundTruth, 'get_ground_truth')
    try:
        truth = call_service(node, client, GetGroundTruth.Request(), 10.0, executor)
    finally:
        node.destroy_client(client)
    if truth is None:
        raise CallError('get_ground_truth did not answer; is mock_robot up?')
    T_true = convert.transform_to_matrix(truth.hand_eye_true)
    return HandEyeError(*frames.transform_error(T_flange_optical, T_true),
                        *frames.transform_error(nominal, T_true))
