"""repeatability_trial: the ISO 9283 trial action (run_trial) and the live `repeatability` topic.

The procedure is core/trial.py; this node gives it a robot made of ROS calls (move_to,
capture_joints, probe/average), stores readings through store.trials, and publishes the
running statistics after every cycle.
"""
from __future__ import annotations

import threading
import time

from cobot_calib_msgs.action import MoveTo, RunTrial
from cobot_calib_msgs.msg import ProximityReading, Repeatability
from cobot_calib_msgs.srv import AverageProximity
import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from cobot_calib_ros import paths
from cobot_calib_ros.ros import convert
from cobot_calib_ros.core.cell import load_cell
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.repeatability import trial as trialmod
from cobot_calib_ros.core.repeatability import PointStats
from cobot_calib_ros.core.sensors.probe import Reading, ReadingStatus
from cobot_calib_ros.store.files import check_id
from cobot_calib_ros.store.trials import TrialStore
from cobot_calib_ros.ros import qos, spin
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCallError, RobotCalls

RESULT_CODE = {'invalid': RunTrial.Result.INVALID_GOAL, 'motion': RunTrial.Result.MOTION_FAILED,
               'probe': RunTrial.Result.PROBE_FAILED, 'canceled': RunTrial.Result.CANCELED}
MOVE_TIMEOUT = 120.0    # [s] for one move_to to finish


class RosRobot:
    """core.trial.Robot over ROS: every call blocks this (action) thread until answered."""

    def __init__(self, answers: spin.Companion, chain: kinematics.Chain, speed: float,
                 probe_window: float, capture_duration: float) -> None:
        self._calls = RobotCalls(answers)
        self._chain, self._speed = chain, speed
        self._probe_window, self._capture_duration = probe_window, capture_duration
        self._probe = answers.node.create_client(AverageProximity, 'probe/average')

    def wait_ready(self, timeout: float = 5.0) -> str:
        """'' when move_to, capture_joints and probe/average answer, else what is missing."""
        missing = []
        if not self._calls.move_client.wait_for_server(timeout_sec=timeout):
            missing.append('move_to (mock_robot)')
        for client, who in ((self._calls.capture_client, 'joint_state_monitor'),
                            (self._probe, 'proximity_sensor')):
            if not client.wait_for_service(timeout_sec=timeout):
                missing.append(f'{client.srv_name} ({who})')
        return f'not available: {", ".join(missing)}; is the node suite up?' if missing else ''

    def probe_range(self) -> trialmod.ProbeRange:
        """The probe's range from proximity_sensor's calibration table (not the cell's)."""
        res = self._average(self._probe_window)
        if res.error_code == AverageProximity.Response.BAD_REQUEST or \
                not 0.0 <= res.min_range < res.max_range:
            raise trialmod.TrialError('probe', f'proximity_sensor gave no probe range '
                                      f'({res.message}); check its calibration table')
        return trialmod.ProbeRange(res.min_range, res.max_range)

    def _average(self, window: float):
        req = AverageProximity.Request(duration=window)
        try:
            return spin.wait(self._probe.call_async(req), window + 5.0)
        except TimeoutError as e:
            raise trialmod.TrialError('probe', f'probe/average: {e}; is the node suite up?')

    def touch(self, name: str) -> np.ndarray:
        try:
            q = self._calls.touch_and_capture(name, self._capture_duration, MOVE_TIMEOUT,
                                              self._speed)
        except RobotCallError as e:
            raise trialmod.TrialError('motion', f'teaching {name}: {e}')
        return kinematics.fk(self._chain, q)

    def move(self, T_base_tool: np.ndarray) -> None:
        goal = MoveTo.Goal(target_type=MoveTo.Goal.TARGET_POSE, speed_scale=self._speed,
                           pose=convert.matrix_to_pose(T_base_tool))
        try:
            self._calls.move(goal, MOVE_TIMEOUT)
        except RobotCallError as e:
            raise trialmod.TrialError('motion', str(e))

    def read(self) -> Reading:
        res = self._average(self._probe_window)
        if res.error_code == AverageProximity.Response.NO_DATA:   # a lost burst: once more
            res = self._average(4 * self._probe_window)
        if res.error_code == AverageProximity.Response.SUCCESS:
            return Reading(res.distance, ReadingStatus.OK)
        if res.error_code == AverageProximity.Response.OUT_OF_RANGE and res.reading_status in (
                ProximityReading.STATUS_BELOW_RANGE, ProximityReading.STATUS_ABOVE_RANGE):
            return Reading(float('nan'), ReadingStatus(res.reading_status))
        raise trialmod.TrialError('probe', f'probe/average: {res.message}')


def stats_msg(trial_id: str, meta: dict, cycles_done: int, stats: PointStats,
              stamp) -> Repeatability:
    msg = Repeatability(trial_id=trial_id, method=meta['method'], axis=meta['axis'],
                        cycles_done=cycles_done, cycles_total=meta['cycles_total'],
                        point_names=list(meta['point_names']))
    msg.header.stamp = stamp
    msg.mean_distance = stats.mean_distance.tolist()
    msg.mean_deviation = stats.mean_deviation.tolist()
    msg.sigma = stats.sigma.tolist()
    msg.rp = stats.rp.tolist()
    msg.rp_all = float(stats.rp_all)
    msg.rp_mm = (stats.rp * 1e3).tolist()
    msg.rp_all_mm = float(stats.rp_all * 1e3)
    return msg


class RepeatabilityTrial(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('repeatability_trial', **kwargs)
        self._declare_parameters()
        self._cell = load_cell(paths.cell_file(self._p('cell_file')), self._p('layout') or None)
        model = kinematics.model_by_name(self._cell.robot)
        self._store = TrialStore(paths.data_dir(self._p('data_dir')))
        self._answers = spin.Companion(self, 'clients')
        self._robot = RosRobot(self._answers, model.chain(tool=self._cell.tool_offset),
                               self._p('speed_scale'), self._p('probe_window'),
                               self._p('capture_duration'))
        self._pub = self.create_publisher(Repeatability, 'repeatability', qos.LATCHED)
        self._busy = threading.Lock()
        self._action = ActionServer(
            self, RunTrial, 'run_trial', execute_callback=self._execute,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        self.get_logger().info(f'trials in {self._store.directory}, layout {self._cell.layout}')

    def destroy_node(self):
        self._answers.destroy()
        return super().destroy_node()

    def _declare_parameters(self) -> None:
        read_once(self, 'cell_file', 'sawyer_close',
                  'Cell YAML (path or name): markers, layouts, nominal tool')
        read_once(self, 'layout', '', 'Marker layout (close | wide); empty = the cell default')
        read_once(self, 'data_dir', '', 'Trials go to <data_dir>/trials; empty = '
                  '$COBOT_CALIB_DATA or ~/.ros/cobot_calib')
        read_once(self, 'probe_window', 0.02, 'Probe averaging window per reading [s]',
                  0.005, 10.0)
        read_once(self, 'capture_duration', 0.3, 'Hold window when teaching a point [s]',
                  0.01, 10.0)
        read_once(self, 'speed_scale', 1.0,
                  'Fraction of the joint velocity limits for trial moves [1]', 0.01, 1.0)
        declare(self, 'approach_distance', 0.005,
                'Retreat along the probe axis before every arrival (unidirectional) [m]',
                0.0, 0.1)

    def _p(self, name: str):
        return self.get_parameter(name).value

    def _accept(self, goal) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning('run_trial rejected: a trial is already running')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        if not self._busy.acquire(blocking=False):
            goal_handle.abort()
            return RunTrial.Result(error_code=RunTrial.Result.INVALID_GOAL,
                                   message='a trial is already running')
        try:
            return self._run(goal_handle)
        finally:
            self._busy.release()

    def _run(self, goal_handle):
        goal, result = goal_handle.request, RunTrial.Result()
        try:
            run, resume = self._prepare(goal, goal_handle)
            result.trial_id = run.plan.trial_id
            data = run.resume(resume) if resume is not None else run.start()
        except trialmod.TrialError as e:
            result.error_code, result.message = RESULT_CODE[e.reason], str(e)
            if e.reason == 'canceled':
                goal_handle.canceled()
            else:
                goal_handle.abort()
            self.get_logger().warning(f'run_trial {result.trial_id}: {e}')
            return result
        stats = trialmod.statistics(data)
        result.statistics = stats_msg(result.trial_id, data.meta, stats.cycles, stats,
                                      self.get_clock().now().to_msg())
        trial_dir = self._store.directory / result.trial_id
        result.csv_path, result.yaml_path = (str(trial_dir / 'distances.csv'),
                                             str(trial_dir / 'trial.yaml'))
        result.message = (f'{stats.cycles} cycles, RP_all {stats.rp_all * 1e3:.4f} mm '
                          f'({data.meta["method"]}, {data.meta["axis"]} axis)')
        goal_handle.succeed()
        self.get_logger().info(f'trial {result.trial_id}: {result.message}')
        return result

    def _prepare(self, goal, goal_handle) -> tuple[trialmod.TrialRun, object]:
        if goal.layout and goal.layout != self._cell.layout:
            raise trialmod.TrialError('invalid', (
                f'layout {goal.layout!r} requested but this node (and the markers) use '
                f'{self._cell.layout!r}; start the suite with layout:={goal.layout}'))
        method = goal.method or 'reference'
        axis = goal.axis or 'z'
        trial_id = goal.trial_id or time.strftime(f'%Y%m%dT%H%M%S-{method}-{axis}')
        try:
            check_id(trial_id)
        except ValueError as e:
            raise trialmod.TrialError('invalid', str(e))
        resume = self._store.load(trial_id) if (self._store.directory / trial_id).exists() \
            else None
        if resume is not None:
            if resume.resume is None:
                raise trialmod.TrialError('invalid', f'trial {trial_id} is complete; pick a '
                                          'new trial_id (empty = a fresh one)')
            method, axis = resume.meta['method'], resume.meta['axis']
            names = resume.meta['point_names']
        else:
            names = self._cell.point_names
        why = self._robot.wait_ready()
        if why:
            raise trialmod.TrialError('motion', why)
        markers = [self._cell.marker(n) for n in names]
        plan = trialmod.Plan(
            trial_id, method, axis, self._cell.layout, markers,
            (resume.meta['cycles_total'] if resume is not None
             else goal.cycles or trialmod.DEFAULT_CYCLES),
            self._robot.probe_range(),
            approach_distance=self._p('approach_distance'))
        feedback = RunTrial.Feedback()

        def on_reading(cycle: int, i: int, distance: float) -> None:
            feedback.cycle, feedback.point_index = cycle, i
            feedback.point_name, feedback.distance = names[i], distance
            goal_handle.publish_feedback(feedback)

        def on_cycle(cycles_done: int, stats: PointStats) -> None:
            msg = stats_msg(trial_id, {'method': method, 'axis': axis,
                                       'cycles_total': plan.cycles, 'point_names': names},
                            cycles_done, stats, self.get_clock().now().to_msg())
            self._pub.publish(msg)
            feedback.statistics = msg
            goal_handle.publish_feedback(feedback)

        run = trialmod.TrialRun(plan, self._robot, self._store, on_reading, on_cycle,
                                lambda: goal_handle.is_cancel_requested)
        return run, resume


def main(args=None) -> None:
    spin.run(RepeatabilityTrial, args, threads=2)


if __name__ == '__main__':
    main()
