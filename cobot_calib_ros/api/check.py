"""The quick health checks of `cobot-calib check` (core.health_checks) as api calls: what to
check against (the cell's results: the active user frame, the active kinematics, through the
cell's rig), the check over the robot port, and its record stored as a result of the cell.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cobot_calib_ros import paths, store
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.robot_port import MoveFailed, PortError, RobotPort
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import rig_of

USER_FRAME, KINEMATICS = 'user-frame', 'kinematics'
DEFAULT_POINTS = ('P1', 'P3', 'P5')


@dataclass(frozen=True)
class Prepared:
    """A check ready to run: its method ('user_frame' | 'kinematics'), the result it checks
    (``against``: an id, or 'nominal'), what it touches (``points``, user frame checks), the
    stale results it goes through (core.provenance), one line saying what is checked, and the
    repository its record goes to."""

    method: str
    against: str
    points: tuple[str, ...]
    stale: tuple
    announce: str
    repo: object
    _run: Callable[[RobotPort], object]

    def run(self, robot: RobotPort):
        """The check over ``robot``: core.health_checks' UserFrameCheck or KinematicsCheck;
        MOTION_FAILED / CAPTURE_FAILED Failure when the robot could not do it."""
        try:
            return self._run(robot)
        except PortError as e:
            return Failure(ErrorCode.MOTION_FAILED if isinstance(e, MoveFailed)
                           else ErrorCode.CAPTURE_FAILED, str(e))


def open_results(cell, data_dir: str = '', db: str | None = None, results_cell: str = '',
                 namespace: str = ''):
    """The repository of ``cell``'s results (``results_cell``: another cell's name)."""
    owner = (ResultsCell(results_cell, cell.robot) if results_cell
             else ResultsCell.of(cell, namespace))
    return store.open(paths.data_dir(data_dir), db, owner)


def prepare(what: str, cell, repo, *, points=DEFAULT_POINTS, poses: int | None = None,
            tolerance_m: float | None = None, model=None) -> Prepared | Failure:
    """The check ``what`` (USER_FRAME or KINEMATICS) of ``cell`` against its active results in
    ``repo``; a Failure saying what is missing (INVALID_INPUT for the request,
    NO_CALIBRATION for no active user frame, STORAGE_FAILED for a store it cannot read)."""
    tolerance = {} if tolerance_m is None else {'tolerance_m': tolerance_m}
    try:
        if what == USER_FRAME:
            return _user_frame(cell, repo, tuple(points), tolerance, model)
        if what == KINEMATICS:
            return _kinematics(cell, repo, poses, tolerance, model)
    except Refusal as e:
        return e.failure
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    except OSError as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'cannot read the results: {e}')
    return Failure(ErrorCode.INVALID_INPUT, f'unknown check {what!r}; one of {USER_FRAME}, '
                   f'{KINEMATICS}')


def _user_frame(cell, repo, points, tolerance, model) -> Prepared | Failure:
    from cobot_calib_ros.core.health_checks import check_user_frame, predicted_points
    unknown = [n for n in points if cell.marker(n) is None]
    if unknown:
        return Failure(ErrorCode.INVALID_INPUT, f'unknown point(s) {unknown}; the cell has '
                       f'{cell.point_names}')
    active = repo.user_frames.active()
    if active is None:
        return Failure(ErrorCode.NO_CALIBRATION, f'no active user frame in the results of '
                       f'cell {repo.cell}; calibrate first (cobot-calib teach, or call '
                       'calibrate_user_frame)')
    rig = rig_of(repo, cell, 'active', model)      # what programs move with
    chain = rig.chain('tcp')
    p_user = np.array([cell.marker(n).nominal_top for n in points])
    predicted = predicted_points(active['inputs'], active['result'], list(points), p_user)
    return Prepared(
        'user_frame', active['id'], points, tuple(rig.active.stale_used('tcp', True)),
        f'checking {active["id"]} at {", ".join(points)} (kinematics '
        f'{rig.active.kinematics_label}, TCP {rig.active.tcp_label})', repo,
        lambda robot: check_user_frame(robot, chain, predicted, list(points), **tolerance))


def _kinematics(cell, repo, poses, tolerance, model) -> Prepared | Failure:
    from cobot_calib_ros.core.health_checks import check_kinematics, KINEMATIC_POSES
    from cobot_calib_ros.core.kinematics import plans
    if cell.spheres is None:
        return Failure(ErrorCode.INVALID_INPUT, f'cell {cell.name!r} has no spheres '
                       '(config/cells/iiwa7_close.yaml has); give --robot-cell')
    rig = rig_of(repo, cell, 'active', model)
    chain = rig.chain('coupling')
    plan, _ = plans.sphere_plan(cell, rig.model, KINEMATIC_POSES if poses is None else poses)
    against = rig.active.kinematics_label
    return Prepared(
        'kinematics', against, (), tuple(rig.active.stale_of(('kinematics',))),
        f'checking the {rig.model.name} model ({against}) on {len(plan)} sphere poses', repo,
        lambda robot: check_kinematics(robot, chain, plan, **tolerance))


def record(prepared: Prepared, check) -> dict | Failure:
    """The check's record (store.records.check_record, with the stale results it went
    through), stored as a result of the cell; STORAGE_FAILED when it cannot be."""
    from cobot_calib_ros.store.records import check_record
    stored = check_record(check, prepared.method, prepared.against)
    stored['stale'] = [s.to_dict() for s in prepared.stale]    # core.provenance: one line each
    try:
        prepared.repo.checks.save(stored)
    except OSError as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'{check.message()}; could not store it: {e}')
    return stored
