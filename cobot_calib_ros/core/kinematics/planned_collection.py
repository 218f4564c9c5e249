"""A planned sphere collection over the robot port: each pose chosen with the data so far.

The loop of :func:`collection.collect` with :class:`planning.SpherePlanner` choosing the poses:
before every move the planner picks the next candidate given every pose measured so far, the
robot couples to it and holds, the pose is logged (``log``, before the next move), the planner
refits and predicts the task-volume error, and ``on_pose`` hears of it; the run ends when the
planner's stopping rule says so (``planner.state.stop``), when cancelled at a pose boundary,
after too many unreachable poses in a row, or when a capture fails. A record's ``index`` is
the candidate's index in the pool, so a resumed run replays the stored rows into the planner
(:meth:`planning.SpherePlanner.resume`) and goes on.

Robot time: the port's ``robot_seconds`` (moves as the robot reports them, holds), split into
``move`` and ``hold``; ``at_hold(s)`` is what the same moves take with a hold of s per pose
(the paper held 1 s).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cobot_calib_ros.core.kinematics.collection import (CollectionRun, Ending,
                                                        MAX_SKIPPED_IN_A_ROW, PoseRecord)
from cobot_calib_ros.core.kinematics.planning import Prediction, SpherePlanner
from cobot_calib_ros.core.robot_port import (Cancelled, Capture, CaptureFailed, MoveFailed,
                                             never, RobotPort, RobotStopped)

PAPER_HOLD = 1.0     # [s] the second paper's hold per pose


@dataclass
class RobotTime:
    """Robot time of a collection [s]: moves as the port reports them, and holds."""

    move: float = 0.0
    hold: float = 0.0
    poses: int = 0

    @property
    def total(self) -> float:
        return self.move + self.hold

    def at_hold(self, hold: float = PAPER_HOLD) -> float:
        """The same moves with ``hold`` [s] at every measured pose."""
        return self.move + self.poses * hold

    def as_dict(self) -> dict[str, float]:
        return {'move_s': self.move, 'hold_s': self.hold, 'poses': self.poses,
                'total_s': self.total, 'at_paper_hold_s': self.at_hold()}


OnPose = Callable[[PoseRecord, Capture, CollectionRun, Prediction], None]


def collect_planned(planner: SpherePlanner, robot: RobotPort,
                    log: Callable[[PoseRecord], None], *, hold: float,
                    cancelled: Cancelled = never, on_pose: OnPose | None = None,
                    max_skipped_in_a_row: int = MAX_SKIPPED_IN_A_ROW
                    ) -> tuple[CollectionRun, RobotTime]:
    """Run the planner's collection on ``robot`` (module doc); the run and its robot time."""
    run, time, in_a_row = CollectionRun(), RobotTime(), 0
    while True:
        stop = planner.stop_reason()
        if stop is not None:
            planner.state.stop = stop
            run.message = stop
            return run, time
        if cancelled():
            return _stopped(run, planner), time
        index = planner.next_pose()
        target = int(planner.pool_target[index])
        before = robot.robot_seconds
        try:
            robot.move_joints(planner.pool_q[index], compliant=True)
        except MoveFailed as e:
            time.move += robot.robot_seconds - before
            if cancelled() or isinstance(e, RobotStopped):   # the stop (collection's doc)
                return _stopped(run, planner), time
            log(PoseRecord(index, target, None, note=str(e)))
            planner.skipped(index)
            run.skipped, in_a_row = run.skipped + 1, in_a_row + 1
            if in_a_row > max_skipped_in_a_row:
                run.ending = Ending.MOTION_FAILED
                run.message = f'{in_a_row} poses in a row failed, the last ({index}): {e}'
                return run, time
            continue
        in_a_row = 0
        moved = robot.robot_seconds
        time.move += moved - before
        try:
            capture = robot.capture(hold)
        except CaptureFailed as e:
            if cancelled():
                return _stopped(run, planner), time
            run.ending, run.message = Ending.CAPTURE_FAILED, f'pose {index}: {e}'
            return run, time
        time.hold += robot.robot_seconds - moved
        time.poses += 1
        record = PoseRecord(index, target, np.asarray(capture.q, dtype=float),
                            capture.sample_count, float(np.max(capture.std)))
        log(record)
        run.recorded += 1
        prediction = planner.measured(index, record.q)
        if on_pose is not None:
            on_pose(record, capture, run, prediction)


def _stopped(run: CollectionRun, planner: SpherePlanner) -> CollectionRun:
    run.ending = Ending.CANCELED
    run.message = f'canceled after {len(planner.q)} planned poses'
    return run
