"""Quick health checks: far less robot time than a calibration, a verdict against the ledger.

``check_user_frame``: touch a few markers (3 by default) and compare each measured point with
where the active user frame puts it. The calibration's own residual at that point (the table's
unevenness, the marker's height error, the robot's kinematic error there: the same today) is
taken off, so what remains is the touch noise plus any move since the calibration:
error_i = p_measured_i - (T_base_user p_user_i - r_i), r_i = M p_user_i - p_base_i as stored
(core.user_frame.result). ``pass`` when every |error_i| is within the tolerance (the drift
WARN tolerance by default), else ``recalibrate``.

``check_kinematics``: visit a few sphere-coupling poses (core.kinematics.plans.sphere_plan, an
even subset: 16 by default) and map each averaged joint reading through the kinematic model in
use to the coupling centre. The poses of one sphere all hold the coupling at its centre, so a
model that is right puts them on one point: the RMS distance of the predicted centres from
their sphere's mean is the check (the truth on the simulated iiwa7: 0.005 mm with the true
model, 0.21 mm with the nominal one). ``pass`` within the tolerance (0.1 mm), else
``recalibrate`` (re-identify).

Both run on a core.robot_port.RobotPort: over ROS (ros.robot_calls) or in-process on the simulation
(sim.robot.DirectRobot), where the verdict can be scored against the ground truth.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.drift import DriftLimits
from cobot_calib_ros.core.frames import apply
from cobot_calib_ros.core.robot_port import Cancelled, check_cancel, never, RobotPort

KINEMATIC_TOLERANCE_M = 1e-4      # [m] RMS spread of the predicted sphere centres
KINEMATIC_POSES = 16

Array = NDArray[np.float64]
HOLD_S = 0.5                      # [s] each touch's capture, as user_frame_solver's default
PASS, RECALIBRATE = 'pass', 'recalibrate'


@dataclass(frozen=True)
class UserFrameCheck:
    names: list[str]
    errors: Array                 # (N, 3) measured - predicted [m]
    tolerance_m: float
    robot_seconds: float          # robot time of the check [s]

    @property
    def max_error_m(self) -> float:
        return float(np.linalg.norm(self.errors, axis=1).max())

    @property
    def mean_error(self) -> Array:
        """(3,) the common part of the errors: how far the frame seems to have moved [m]."""
        return self.errors.mean(axis=0)

    @property
    def verdict(self) -> str:
        return PASS if self.max_error_m <= self.tolerance_m else RECALIBRATE

    def stored(self) -> tuple[dict, dict]:
        """(inputs, result) as a stored check keeps them (store.records.check_record)."""
        return ({'point_names': self.names, 'tolerance_m': self.tolerance_m},
                {'verdict': self.verdict, 'errors': self.errors, 'max_error_m': self.max_error_m,
                 'mean_error': self.mean_error, 'robot_seconds': self.robot_seconds,
                 'message': self.message()})

    def message(self) -> str:
        worst = self.names[int(np.argmax(np.linalg.norm(self.errors, axis=1)))]
        return (f'{self.verdict}: largest point error {self.max_error_m * 1e3:.3f} mm at '
                f'{worst} (tolerance {self.tolerance_m * 1e3:.3f} mm), mean offset '
                f'{np.linalg.norm(self.mean_error) * 1e3:.3f} mm; robot time '
                f'{self.robot_seconds:.1f} s')


def predicted_points(record_inputs: Mapping, record_result: Mapping,
                     names: Sequence[str], p_user: ArrayLike) -> Array:
    """Where the stored user frame puts ``names`` (p_user (N, 3) [m]), minus the stored
    residual of those the calibration measured."""
    T = np.asarray(record_result['T_base_user'], dtype=float)
    predicted = apply(T, np.asarray(p_user, dtype=float))
    stored = list(record_inputs.get('point_names', []))
    residuals = np.asarray(record_result.get('residuals', []), dtype=float).reshape(-1, 3)
    for i, name in enumerate(names):
        if name in stored and len(residuals) == len(stored):
            predicted[i] -= residuals[stored.index(name)]
    return predicted


def check_user_frame(robot: RobotPort, chain: kinematics.Chain, predicted: ArrayLike,
                     names: Sequence[str], tolerance_m: float = DriftLimits().warn_m,
                     hold_s: float = HOLD_S, cancelled: Cancelled = never) -> UserFrameCheck:
    """Touch ``names``, capture, forward kinematics with ``chain``; compare with ``predicted``
    (N, 3) [m] (:func:`predicted_points`). PortError as the port raises it."""
    start = robot.robot_seconds
    measured = []
    for name in names:
        check_cancel(cancelled, f'the touch of {name}')
        robot.touch(name)
        measured.append(kinematics.fk(chain, robot.capture(hold_s).q)[:3, 3])
    errors = np.array(measured) - np.asarray(predicted, dtype=float)
    return UserFrameCheck(list(names), errors, tolerance_m, robot.robot_seconds - start)


@dataclass(frozen=True)
class KinematicsCheck:
    spread_rms_m: float           # RMS distance of the predicted centres from their sphere's mean
    poses: int                    # poses recorded (skipped ones left out)
    spheres: int
    tolerance_m: float
    robot_seconds: float

    @property
    def verdict(self) -> str:
        return PASS if self.spread_rms_m <= self.tolerance_m else RECALIBRATE

    def stored(self) -> tuple[dict, dict]:
        """(inputs, result) as a stored check keeps them (store.records.check_record)."""
        return ({'poses': self.poses, 'spheres': self.spheres, 'tolerance_m': self.tolerance_m},
                {'verdict': self.verdict, 'spread_rms_m': self.spread_rms_m,
                 'robot_seconds': self.robot_seconds, 'message': self.message()})

    def message(self) -> str:
        return (f'{self.verdict}: the model puts {self.poses} poses on {self.spheres} spheres '
                f'{self.spread_rms_m * 1e3:.3f} mm RMS off their common centres (tolerance '
                f'{self.tolerance_m * 1e3:.3f} mm); robot time {self.robot_seconds:.1f} s')


def sphere_spread(chain: kinematics.Chain, q: ArrayLike, target: ArrayLike) -> float:
    """RMS distance [m] of the coupling centres fk(chain, q_i) from the mean of their sphere's."""
    q, target = np.asarray(q, dtype=float), np.asarray(target)
    p = np.array([kinematics.fk(chain, qi)[:3, 3] for qi in q])
    deviations = np.concatenate([p[target == k] - p[target == k].mean(axis=0)
                                 for k in np.unique(target)])
    return float(np.sqrt(np.mean(np.sum(deviations ** 2, axis=1))))


def check_kinematics(robot: RobotPort, chain: kinematics.Chain, plan: Sequence[Mapping],
                     tolerance_m: float = KINEMATIC_TOLERANCE_M, hold_s: float = HOLD_S,
                     cancelled: Cancelled = never) -> KinematicsCheck:
    """Visit ``plan`` (sphere steps with 'q', 'target'; core.kinematics.collection), then the
    spread of the centres ``chain`` (to the coupling) predicts. ValueError: fewer than two
    poses on any sphere were recorded; PortError as the port raises it."""
    from cobot_calib_ros.core.kinematics.collection import collect, Ending
    start, records = robot.robot_seconds, []
    run = collect(plan, 0, robot, records.append, hold=hold_s, cancelled=cancelled)
    if run.ending is not Ending.DONE:
        raise ValueError(f'the check stopped: {run.message}')
    done = [r for r in records if r.q is not None]
    targets = np.array([r.target for r in done])
    if not done or min(np.sum(targets == k) for k in np.unique(targets)) < 2:
        raise ValueError(f'{len(done)} poses recorded: each sphere needs two or more')
    spread = sphere_spread(chain, [r.q for r in done], targets)
    return KinematicsCheck(spread, len(done), len(np.unique(targets)), tolerance_m,
                           robot.robot_seconds - start)
