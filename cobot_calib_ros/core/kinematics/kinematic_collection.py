"""The kinematic collection as one core procedure (issue 39.2): set-up, resume, visit, robot time.

:func:`new_collection` sets a collection up from a request in SI: the sphere plan (the paper's
grid, or the planner's candidates and settings for a planned one) or laser-tracker
configurations, with what a resume needs stored beside the plan. :func:`collect_kinematics`
visits a collection over the robot port from the poses it already has (a resume): the stored
plan from its first pose without a row (core.kinematics.collection), or, planned, the poses the
planner chooses with the data so far (core.kinematics.planned_collection), the planner's state
carried over from the run before. Every pose goes to ``log`` before the next move; ``progress``
hears of each with the planner's prediction [m]. ``cancelled()`` is looked at between poses.

The procedure returns :class:`Collected` when the plan (or the planner's stopping rule) is
done, else an :class:`Unfinished` Failure (CANCELED, MOTION_FAILED, CAPTURE_FAILED) that still
carries what was collected, so the caller can store the planning state and say how to resume.
Storing the collection is the caller's (api.kinematics.collect): no store here.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.cell import Cell
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.collection import collect, CollectionRun, Ending, PoseRecord
from cobot_calib_ros.core.kinematics.model import KinematicModel
from cobot_calib_ros.core.kinematics.planned_collection import collect_planned, RobotTime
from cobot_calib_ros.core.kinematics.planning import (arm_grid_deg, PlanSettings, Prediction,
                                                      sphere_candidates, SpherePlanner,
                                                      tilt_grid_deg, TILT_STEP_DEG,
                                                      too_few_poses, turn_grid_deg)
from cobot_calib_ros.core.robot_port import Cancelled, Capture, never, RobotPort

Array = NDArray[np.float64]
SOURCES = ('spheres', 'laser_tracker')
PLANNED_MAX_POSES = 50
PLANNING_TASK_SEED = 1      # the task volume's configurations (the validation set is seed 0)


@dataclass(frozen=True)
class CollectionRequest:
    """What to collect, in SI. ``max_configs``: poses of the grid or tracker set (0: all);
    planned (spheres only): up to ``max_poses``, stopping at a predicted max error of
    ``target_error_m`` or a gain under ``min_gain``, candidates in ``tilt_step_rad`` steps
    (tilts, turns about the approach axis, arm angles)."""

    source: str = 'spheres'
    region: str = 'volume'
    planned: bool = False
    max_configs: int = 0
    max_poses: int = 0
    target_error_m: float = 0.0
    min_gain: float = 0.0
    seed: int = 0
    tilt_step_rad: float = math.radians(TILT_STEP_DEG)


@dataclass(frozen=True)
class NewCollection:
    """A collection's set-up, as the store creates it: its id prefix, plan and metadata."""

    source: str
    prefix: str                     # a new id starts with it ('spheres', 'tracker-volume')
    targets: list[str]
    plan: list[dict]
    extra: dict[str, Any]           # metadata beside the plan (planning settings, distances)


@dataclass(frozen=True)
class Resume:
    """What a stored collection already has: its ok rows' plan indices and joints, the
    skipped ones (index -> why), and where the plain visit goes on."""

    index: Sequence[int] = ()
    q: Array = field(default_factory=lambda: np.zeros((0, 0)))
    skipped: Mapping[int, str] = field(default_factory=dict)
    next_index: int = 0


@dataclass(frozen=True)
class PoseProgress:
    """One recorded pose of collection ``collection_id``, for feedback: counts over the
    whole collection (a resume goes on counting), robot time of this run [s], the prediction
    (planned; inf before it has one, None for a plain collection)."""

    collection_id: str
    index: int
    total: int
    target: str
    recorded: int
    skipped: int
    robot_time_s: float
    capture: Capture
    prediction: Prediction | None = None


@dataclass(frozen=True)
class Collected:
    """A collection's run: the poses it has (recorded, skipped: the whole collection), this
    run's robot time, the stop reason and last predicted max error [m] of a planned one, its
    planning metadata to store (None: not planned), and a line on how it ended."""

    collection_id: str
    recorded: int
    skipped: int
    time: RobotTime
    message: str
    stop_reason: str = ''
    predicted_max_m: float = math.inf
    planning: dict | None = None


@dataclass(frozen=True)
class Unfinished(Failure):
    """A collection that ended before its plan: falsy with its cause, and what it has."""

    collected: Collected | None = None


OnProgress = Callable[[PoseProgress], None]


def new_collection(cell: Cell, model: KinematicModel, request: CollectionRequest,
                   say: Callable[[str], None] = lambda _: None) -> NewCollection | Failure:
    """The set-up of a new collection (module doc); INVALID_INPUT saying what to give for a
    request it cannot plan (checked before the candidate IK: a second, not a minute)."""
    source = request.source or 'spheres'
    if source not in SOURCES:
        return Failure(ErrorCode.INVALID_INPUT, f'unknown source {source!r}; use spheres or '
                       'laser_tracker')
    if request.planned and source != 'spheres':
        return Failure(ErrorCode.INVALID_INPUT, 'planned applies to source spheres only')
    if cell.spheres is None:
        return Failure(ErrorCode.NOT_AVAILABLE, f'cell {cell.name} has no spheres: section '
                       '(sphere plate and coupling); add it to the cell file')
    coupling = cell.spheres.T_flange_coupling[:3, 3]
    if source == 'laser_tracker':
        region = request.region or 'volume'
        plan = plans.tracker_plan(cell, model, region,
                                  request.max_configs or plans.TRACKER_CONFIGS, request.seed)
        return NewCollection(source, f'tracker-{region}', [], plan, {
            'region': region, 'seed': request.seed, 'p_flange_coupling': coupling})
    extra: dict[str, Any] = {'known_distances': cell.spheres.known_distances(),
                             'p_flange_coupling': coupling}
    if request.planned:
        step_deg = math.degrees(request.tilt_step_rad)
        try:
            tilts = tilt_grid_deg(step_deg)
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, f'candidate tilt step: {e}')
        max_poses = request.max_poses or PLANNED_MAX_POSES
        problem = too_few_poses(cell, model, max_poses)
        if problem:
            return Failure(ErrorCode.INVALID_INPUT, problem)
        say(f'planned collection: solving IK for the candidate poses (tilts in '
            f'{step_deg:.4g} deg steps)')
        plan, unreachable = sphere_candidates(cell, model, tilts, arm_grid_deg(step_deg),
                                              turn_grid_deg(step_deg))
        say(f'{len(plan)} candidates reachable, {len(unreachable)} not')
        settings = PlanSettings(max_poses=max_poses, target_mm=request.target_error_m * 1e3,
                                min_gain=request.min_gain)
        task = plans.tracker_plan(cell, model, 'volume', plans.TRACKER_CONFIGS,
                                  PLANNING_TASK_SEED)
        extra['planning'] = {'settings': vars(settings), 'task_q': [s['q'] for s in task]}
    else:
        plan, unreachable = plans.sphere_plan(cell, model, request.max_configs)
    extra['unreachable_in_plan'] = unreachable
    return NewCollection(source, 'spheres', list(cell.spheres.names), plan, extra)


def collect_kinematics(model: KinematicModel, meta: Mapping[str, Any], resume: Resume,
                       robot: RobotPort, log: Callable[[PoseRecord], None], *, hold: float,
                       cancelled: Cancelled = never, progress: OnProgress | None = None
                       ) -> Collected | Unfinished:
    """Visit the collection ``meta`` (a NewCollection as stored, with its 'id') on ``robot``
    from what it has (``resume``); see the module doc."""
    if 'planning' in meta:
        return _planned(model, meta, resume, robot, log, hold, cancelled, progress)
    plan, laser = meta['plan'], meta['source'] == 'laser_tracker'
    before, skipped_before = len(resume.index), len(resume.skipped)
    start = robot.robot_seconds

    def on_pose(record: PoseRecord, capture: Capture, run: CollectionRun) -> None:
        if progress is not None:
            target = 'tracker' if laser else meta['targets'][record.target]
            progress(PoseProgress(
                meta['id'], record.index, len(plan), target, before + run.recorded,
                skipped_before + run.skipped, robot.robot_seconds - start, capture))

    run = collect(plan, resume.next_index, robot, log, hold=hold, laser=laser,
                  cancelled=cancelled, on_pose=on_pose)
    total = robot.robot_seconds - start
    time = RobotTime(total - run.recorded * hold, run.recorded * hold, run.recorded)
    collected = Collected(meta['id'], before + run.recorded, skipped_before + run.skipped, time,
                          f'per pose: {run.per_pose()}')
    return _ended(run, collected)


def _planned(model: KinematicModel, meta: Mapping[str, Any], resume: Resume,
             robot: RobotPort, log: Callable[[PoseRecord], None], hold: float,
             cancelled: Cancelled, progress: OnProgress | None) -> Collected | Unfinished:
    """The planned collection, from the poses stored so far; its planning state to store."""
    planning = meta['planning']
    coupling = meta.get('p_flange_coupling', meta.get('coupling_offset_xyz'))  # legacy name
    planner = SpherePlanner(model, meta['plan'], meta['known_distances'], coupling,
                            planning['task_q'],
                            PlanSettings(**planning['settings']))
    planner.resume(list(resume.index), resume.q, list(resume.skipped))
    before = planning.get('state')
    if before:          # a resumed collection keeps the plan made before the robot moved
        planner.state.initial_plan = before['initial_plan']
        planner.state.initial_predictions = [Prediction.from_dict(p)
                                             for p in before['initial_predictions']]
        # ... and the rest of its planned set, in its order (stored since issue 38.5)
        planner.state.route = [i for i in before.get('route', []) if planner.available[i]]
    else:
        planner.start()
    start = robot.robot_seconds

    def on_pose(record: PoseRecord, capture: Capture, run: CollectionRun,
                prediction: Prediction) -> None:
        if progress is not None:
            progress(PoseProgress(
                meta['id'], len(planner.q) - 1, planner.settings.max_poses,
                meta['targets'][record.target], len(planner.q), len(planner.state.skipped),
                robot.robot_seconds - start, capture, prediction))

    run, time = collect_planned(planner, robot, log, hold=hold, on_pose=on_pose,
                                cancelled=cancelled)
    last = planner.state.predictions[-1] if planner.state.predictions else None
    done = planning.get('robot_time', {})
    total = RobotTime(time.move + done.get('move_s', 0.0), time.hold + done.get('hold_s', 0.0),
                      time.poses + int(done.get('poses', 0)))
    collected = Collected(
        meta['id'], len(planner.q), len(planner.state.skipped), time,
        f'stopped on {run.message}', planner.state.stop or '',
        last.max_m if last else math.inf,
        {**planning, 'state': planner.state.as_dict(), 'robot_time': total.as_dict()})
    return _ended(run, collected)


_CAUSES = {Ending.CANCELED: ErrorCode.CANCELED, Ending.MOTION_FAILED: ErrorCode.MOTION_FAILED,
           Ending.CAPTURE_FAILED: ErrorCode.CAPTURE_FAILED}


def _ended(run: CollectionRun, collected: Collected) -> Collected | Unfinished:
    if run.ending is Ending.DONE:
        return collected
    return Unfinished(_CAUSES[run.ending], f'{collected.collection_id}: {run.message}; give '
                      'the same collection_id to resume', collected)
