"""Kinematic data collection over the robot port: the second paper's Algorithm 2.

A collection visits a stored plan (core.kinematics.plans: sphere poses, or laser-tracker
configurations) pose by pose from ``start``. At each pose the robot moves (compliant for the
spheres: under impedance control the coupling self-centres on the sphere), the joints are
averaged over a hold, and for a laser tracker the tool position is measured; every pose goes to
``log`` before the next move, so a collection that stops (Ctrl-C, a crash) resumes at the first
pose without a record. A pose the robot cannot reach is logged as skipped; more than
``max_skipped_in_a_row`` in a row end the run, as does a capture that fails. ``cancelled()``
is looked at between poses (never inside a port call): the run stops at that pose boundary. A
move or capture that fails once ``cancelled()`` is True failed because of the stop (a node
shutting down ends its calls in flight): the run ends cancelled at that pose, which is not
logged, so a resume visits it.

Runs the same over ROS (kinematic_identifier with ros.robot_calls) and in-process on the
simulation (sim.robot.DirectRobot), where a test knows the truth.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.robot_port import (Cancelled, Capture, CaptureFailed, MoveFailed,
                                             never, RobotPort, RobotStopped)

Array = NDArray[np.float64]
MAX_SKIPPED_IN_A_ROW = 20     # more unreachable poses in a row than this end the collection


@dataclass(frozen=True)
class PoseRecord:
    """One visited pose of the plan, as it is stored."""

    index: int                  # in the plan
    target: int                 # the plan step's target (a sphere's index; -1: the tracker)
    q: Array | None             # (n,) averaged joints [rad]; None: skipped (note says why)
    sample_count: int = 0       # joint readings averaged
    std_max: float = math.nan   # largest joint standard deviation over the hold [rad]
    p: Array | None = None      # (3,) laser-tracker measurement, tracker frame [m]
    note: str = ''


class Ending(Enum):
    DONE = 'done'               # every pose of the plan has a record
    CANCELED = 'canceled'       # cancelled() at a pose boundary
    MOTION_FAILED = 'motion'    # too many unreachable poses in a row
    CAPTURE_FAILED = 'capture'  # a capture or measurement did not come


@dataclass
class CollectionRun:
    """What a run did: how it ended (``message`` says where and why), the poses recorded and
    skipped by this run, the next plan index to visit, wall time per part [s]."""

    ending: Ending = Ending.DONE
    message: str = ''
    recorded: int = 0
    skipped: int = 0
    next_index: int = 0
    seconds: dict[str, float] = field(default_factory=lambda: {'move': 0.0, 'capture': 0.0,
                                                               'store': 0.0})

    def per_pose(self) -> str:
        """'move 31 ms, capture 52 ms, store 1 ms': mean wall time per recorded pose."""
        return ', '.join(f'{k} {v / max(self.recorded, 1) * 1e3:.0f} ms'
                         for k, v in self.seconds.items())


def collect(plan: Sequence[Mapping[str, Any]], start: int, robot: RobotPort,
            log: Callable[[PoseRecord], None], *, hold: float, laser: bool = False,
            cancelled: Cancelled = never,
            on_pose: Callable[[PoseRecord, Capture, CollectionRun], None] | None = None,
            max_skipped_in_a_row: int = MAX_SKIPPED_IN_A_ROW) -> CollectionRun:
    """Visit ``plan`` (steps with 'q' [rad] and 'target') from index ``start``; see the module
    doc. ``log`` stores a record (it raises on a storage error, which ends the run);
    ``on_pose`` is told of each recorded pose (feedback, a capture mark)."""
    run, in_a_row = CollectionRun(next_index=start), 0
    clock = time.perf_counter
    for i in range(start, len(plan)):
        run.next_index = i
        if cancelled():
            return _stopped_at(run, i, len(plan))
        step = plan[i]
        t0 = clock()
        try:
            robot.move_joints(np.asarray(step['q'], dtype=float), compliant=not laser)
        except MoveFailed as e:
            if cancelled():
                return _stopped_at(run, i, len(plan))
            if isinstance(e, RobotStopped):     # before this node heard of the stop, if ever
                return _stopped_at(run, i, len(plan), str(e))
            log(PoseRecord(i, int(step['target']), None, note=str(e)))
            run.skipped, in_a_row = run.skipped + 1, in_a_row + 1
            if in_a_row > max_skipped_in_a_row:
                run.next_index = i + 1
                run.ending = Ending.MOTION_FAILED
                run.message = f'{in_a_row} poses in a row failed, the last ({i}): {e}'
                return run
            continue
        in_a_row = 0
        t1 = clock()
        try:
            capture = robot.capture(hold)
            p = robot.measure_position() if laser else None
        except CaptureFailed as e:
            if cancelled():
                return _stopped_at(run, i, len(plan))
            run.ending, run.message = Ending.CAPTURE_FAILED, f'pose {i}: {e}'
            return run
        t2 = clock()
        record = PoseRecord(i, int(step['target']), np.asarray(capture.q, dtype=float),
                            capture.sample_count, float(np.max(capture.std)), p)
        log(record)
        run.seconds['move'] += t1 - t0
        run.seconds['capture'] += t2 - t1
        run.seconds['store'] += clock() - t2
        run.recorded += 1
        if on_pose is not None:
            on_pose(record, capture, run)
    run.next_index = len(plan)
    return run


def _stopped_at(run: CollectionRun, index: int, poses: int, robot: str = '') -> CollectionRun:
    """``run`` ended cancelled at plan index ``index`` (not logged: a resume visits it);
    ``robot``: why the robot stopped the move itself, when it did."""
    run.next_index = index
    run.ending = Ending.CANCELED
    run.message = (f'stopped at pose {index} of {poses}: {robot}' if robot else
                   f'canceled at pose {index} of {poses}')
    return run
