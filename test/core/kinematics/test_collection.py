"""core.kinematics.collection (Algorithm 2) in-process on the simulated Sawyer (DirectRobot):
where the coupling lands, cancelling at a pose boundary and resuming, unreachable poses,
a failed capture, laser-tracker measurements against the truth."""
import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.collection import collect, Ending
from cobot_calib_ros.core.robot_port import CaptureFailed, MoveFailed, RobotStopped
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

SIM = load_simulation(cell_file('sawyer_close'))
HOLD = 0.02      # [s]


@pytest.fixture(scope='module')
def plan():
    steps, _ = plans.sphere_plan(SIM.cell, kinematics.model_by_name(SIM.cell.robot), 30)
    return steps


def _robot(seed: int = 1) -> DirectRobot:
    return DirectRobot(SimRobot(SIM, seed_offset=seed), SIM.probe)


def test_every_pose_is_logged_with_the_coupling_on_its_sphere(plan):
    robot, log, fed = _robot(), [], []
    run = collect(plan, 0, robot, log.append, hold=HOLD,
                  on_pose=lambda record, capture, run: fed.append(run.recorded))
    assert run.ending is Ending.DONE and run.next_index == len(plan) == 30
    assert [r.index for r in log] == list(range(30)) and run.recorded == 30 and not run.skipped
    assert fed == list(range(1, 31))
    spheres, arm = SIM.spheres, robot.sim
    for record in log:
        assert record.target == plan[record.index]['target'] and record.p is None
        assert record.sample_count == round(HOLD * SIM.joint_states_hz)
        # the averaged encoders, mapped through the TRUE chain to the coupling: on the true
        # centre of the step's sphere within the compliance and encoder noise (<= 11 um)
        centre = kinematics.fk(arm.coupling, record.q)[:3, 3]
        assert np.linalg.norm(centre - spheres.centres_base[record.target]) < 2e-5
        # and not where the nominal plan put it: the robot's kinematic errors are in the data
        planned = kinematics.fk(arm.coupling, np.array(plan[record.index]['q']))[:3, 3]
        assert np.linalg.norm(planned - centre) > 1e-3          # 2.5-3.4 mm measured


def test_a_cancel_stops_at_the_next_pose_boundary_and_the_run_resumes_there(plan):
    robot, log = _robot(), []
    run = collect(plan, 0, robot, log.append, hold=HOLD, cancelled=lambda: len(log) >= 7)
    assert run.ending is Ending.CANCELED and run.next_index == 7 == len(log)
    assert run.message == 'canceled at pose 7 of 30'
    moves = robot.moves
    rest = collect(plan, run.next_index, robot, log.append, hold=HOLD)
    assert rest.ending is Ending.DONE and rest.recorded == 23
    assert robot.moves == moves + 23                    # no pose visited twice
    assert [r.index for r in log] == list(range(30))


def test_a_move_that_fails_after_the_stop_ends_the_run_there_not_logged_as_skipped(plan):
    """A node shutting down ends its move in flight (issue 31 item 3): that pose was not
    unreachable, so it is not logged; a resume visits it."""
    robot, log, stop = _robot(), [], []
    move = robot.move_joints

    def stopped_midway(q, **kwargs):
        if len(log) == 4:
            stop.append(True)
            raise MoveFailed('move_to: the node is shutting down')
        return move(q, **kwargs)

    robot.move_joints = stopped_midway
    run = collect(plan, 0, robot, log.append, hold=HOLD, cancelled=lambda: bool(stop))
    assert run.ending is Ending.CANCELED and run.next_index == 4
    assert run.message == 'canceled at pose 4 of 30'
    assert [r.index for r in log] == [0, 1, 2, 3] and all(r.q is not None for r in log)


def test_a_move_the_robot_stopped_before_this_node_heard_of_the_stop_is_not_skipped(plan):
    """Ctrl-C to up's process group reaches mock_robot and kinematic_identifier at once: the
    robot may end the move in flight (its result CANCELED: RobotStopped) before this node's
    own stop is seen. That pose was not unreachable (it was logged skipped in a full run of
    the merged suite, and a resume never visited it again): the run ends there."""
    robot, log = _robot(), []
    move = robot.move_joints

    def robot_shutting_down(q, **kwargs):
        if len(log) == 4:
            raise RobotStopped('move_to: the mock robot is shutting down (Ctrl-C or SIGTERM)')
        return move(q, **kwargs)

    robot.move_joints = robot_shutting_down
    run = collect(plan, 0, robot, log.append, hold=HOLD)
    assert run.ending is Ending.CANCELED and run.next_index == 4 and run.skipped == 0
    assert run.message == ('stopped at pose 4 of 30: move_to: the mock robot is shutting down '
                           '(Ctrl-C or SIGTERM)')
    assert [r.index for r in log] == [0, 1, 2, 3] and all(r.q is not None for r in log)


def test_unreachable_poses_are_skipped_until_too_many_in_a_row(plan):
    outside = [{'q': [9.0] * 7, 'target': 0}] * 3
    log = []
    run = collect(outside + plan[:2], 0, _robot(), log.append, hold=HOLD)
    assert run.ending is Ending.DONE and (run.skipped, run.recorded) == (3, 2)
    assert [r.q is None for r in log] == [True, True, True, False, False]
    assert 'outside the limits' in log[0].note
    log = []
    run = collect(outside + plan[:2], 0, _robot(), log.append, hold=HOLD,
                  max_skipped_in_a_row=2)
    assert run.ending is Ending.MOTION_FAILED and run.next_index == 3 and len(log) == 3
    assert run.message.startswith('3 poses in a row failed, the last (2): ')


def test_a_failed_capture_ends_the_run_at_that_pose(plan):
    class NoJoints(DirectRobot):
        def capture(self, duration):
            raise CaptureFailed('capture_joints: no joint_states for 0.02 s')

    log = []
    run = collect(plan, 4, NoJoints(SimRobot(SIM), SIM.probe), log.append, hold=HOLD)
    assert run.ending is Ending.CAPTURE_FAILED and run.next_index == 4 and not log
    assert run.message == 'pose 4: capture_joints: no joint_states for 0.02 s'


def test_laser_tracker_configurations_are_measured_where_the_true_robot_is():
    model = kinematics.model_by_name(SIM.cell.robot)
    steps = plans.tracker_plan(SIM.cell, model, 'volume', 5)
    robot, log = _robot(), []
    run = collect(steps, 0, robot, log.append, hold=HOLD, laser=True)
    assert run.ending is Ending.DONE and len(log) == 5
    tracker = SIM.spheres.tracker
    for record in log:
        true = kinematics.fk(robot.sim.coupling, record.q)[:3, 3]
        measured = frames.apply(tracker.T_base_tracker, record.p)
        assert record.target == -1
        assert np.linalg.norm(measured - true) < 6 * tracker.sigma + 1e-5
