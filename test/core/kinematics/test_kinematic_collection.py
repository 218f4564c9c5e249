"""core.kinematics.kinematic_collection in-process on the simulated Sawyer (DirectRobot), no
store: a planned collection cancelled at a pose boundary and resumed from what it logged, its
planning state and robot time carried over, its prediction in metres."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics import model_for
from cobot_calib_ros.core.kinematics.kinematic_collection import (
    collect_kinematics, Collected, CollectionRequest, new_collection, Resume, Unfinished)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

SIM = load_simulation(cell_file('sawyer_close'))
MODEL = model_for(SIM.cell)
HOLD = 0.02     # [s]


@pytest.fixture(scope='module')
def planned():
    """A planned collection's set-up: candidates on a 45 deg tilt grid (less IK), 12 poses."""
    new = new_collection(SIM.cell, MODEL, CollectionRequest(
        planned=True, max_poses=12, target_error_m=1e-9, tilt_step_rad=math.radians(45)))
    assert new, new
    return new


def _resume(log) -> Resume:
    ok = [r for r in log if r.q is not None]
    return Resume([r.index for r in ok], np.array([r.q for r in ok]).reshape(-1, 7),
                  {r.index: r.note for r in log if r.q is None})


def test_a_planned_collection_resumes_with_its_plan_and_robot_time(planned):
    assert planned.extra['planning']['settings']['max_poses'] == 12
    assert planned.extra['planning']['settings']['target_mm'] == pytest.approx(1e-6)
    meta = {'id': 'planned', 'source': 'spheres', 'targets': planned.targets,
            'plan': planned.plan, **planned.extra}
    robot, log, seen = DirectRobot(SimRobot(SIM, seed_offset=1), SIM.probe), [], []
    first = collect_kinematics(MODEL, meta, Resume(q=np.zeros((0, 7))), robot, log.append,
                               hold=HOLD, cancelled=lambda: len(seen) >= 5,
                               progress=seen.append)
    assert isinstance(first, Unfinished) and first.code == ErrorCode.CANCELED
    assert first.message == ('planned: canceled after 5 planned poses; give the same '
                             'collection_id to resume')
    state = first.collected.planning['state']
    assert len(state['chosen']) == 5 and len(state['initial_plan']) == 12
    assert first.collected.planning['robot_time']['poses'] == 5
    moved = robot.robot_seconds
    resumed = collect_kinematics(MODEL, {**meta, 'planning': first.collected.planning},
                                 _resume(log), robot, log.append, hold=HOLD,
                                 progress=seen.append)
    assert isinstance(resumed, Collected), resumed
    assert resumed.stop_reason == 'max_poses: 12 poses measured' == resumed.planning['state'][
        'stop']
    assert resumed.recorded == 12 and [p.recorded for p in seen] == list(range(1, 13))
    assert resumed.planning['state']['initial_plan'] == state['initial_plan']
    # robot time: this run's in the result, the collection's in its planning
    assert resumed.time.total == pytest.approx(robot.robot_seconds - moved)
    assert resumed.planning['robot_time']['total_s'] == pytest.approx(robot.robot_seconds)
    assert resumed.planning['robot_time']['poses'] == 12 == resumed.time.poses + 5
    # the predictions [m]: none while the data cannot determine the model, then a few um
    predicted = [p.prediction.max_m for p in seen]
    assert math.isinf(predicted[0]) and resumed.predicted_max_m == predicted[-1]
    assert 1e-7 < resumed.predicted_max_m < 1e-4
    assert [r.index for r in log] == resumed.planning['state']['chosen']
