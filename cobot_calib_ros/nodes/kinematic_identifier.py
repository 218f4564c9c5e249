"""kinematic_identifier: sphere-coupling data collection and kinematic identification.

Two actions, one long job at a time (the node spins two threads: one runs the job, the other
answers cancels and feedback). Each goal handler is parameters in, one api.kinematics call, the
result out (issue 39.2); the procedures run the same in-process on the simulation.

- ``collect_sphere_data`` (api.kinematics.collect over ros.robot_calls, the robot port; the
  procedure is core.kinematics.kinematic_collection): the second paper's Algorithm 2 through
  ``move_to`` (compliant: the coupling self-centres on the sphere) and ``capture_joints``, or
  laser-tracker configurations through ``laser_tracker/measure``; every pose is stored as it
  is measured and a collection resumes after a restart. ``planned``: each sphere pose is
  chosen with the data so far (core.kinematics.planning), with a predicted accuracy [m] and a
  stopping rule. Every pose is published as a capture mark, on collection_progress and as
  live-view markers.
- ``identify_kinematics`` (api.kinematics.identify): the one identification engine
  (core.kinematics.kinematic_calibration), validation on laser-tracker collections, the
  gate, stored as JSON + YAML + calibrated URDF and made the active kinematic calibration
  that user_frame_solver and repeatability_trial use; robot_description follows it.
"""
from __future__ import annotations

import math
import sys
import threading

from cobot_calib_msgs.action import CollectSphereData, IdentifyKinematics
from cobot_calib_msgs.msg import CaptureMark, CollectionProgress, ErrorStats
import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from std_msgs.msg import Header, String
from visualization_msgs.msg import MarkerArray

from cobot_calib_ros.api import kinematics as kinematics_api
from cobot_calib_ros.api.kinematics import GateRefused, Identified
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification.gates import (
    DeviationBounds, MAX_DEVIATION_M, MAX_DEVIATION_RAD)
from cobot_calib_ros.core.kinematics.kinematic_collection import (CollectionRequest,
                                                                  PoseProgress, Unfinished)
from cobot_calib_ros.core.kinematics.planning import TILT_STEP_DEG
from cobot_calib_ros.core.rig import Rig
from cobot_calib_ros.ros import markers, marks, qos, spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns, ns_to_stamp
from cobot_calib_ros.nodes.job_node import JobNode

Collect, Identify = CollectSphereData, IdentifyKinematics
DESCRIPTION_CHECK_PERIOD = 2.0   # [s] between looks at the active calibration (robot_description)


class KinematicIdentifier(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('kinematic_identifier', job='a collection or identification',
                         cell_help='Cell YAML (path or name): robot, home, the sphere plate '
                         'and coupling', data_help='Collections go to <data_dir>/kinematic_data, '
                         'results to <data_dir>/kinematics', **kwargs)
        self._declare_parameters()
        repository = self._repository()
        self._collections = repository.collections
        kinematics_dir = repository.kinematics.directory
        self._robot = RobotCalls(self._answers)
        self._health.watch(capture_retries=lambda: self._robot.capture_retries)
        self._health.set(OK, 'idle', job='')
        self._create_publishers()
        group = ReentrantCallbackGroup()
        self._actions = [ActionServer(
            self, Action, name, execute_callback=run, goal_callback=self._accept,
            cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group)
            for Action, name, run in ((Collect, 'collect_sphere_data', self._on_collect),
                                      (Identify, 'identify_kinematics', self._on_identify))]
        self.get_logger().info(f'{self._cell.robot} cell "{self._cell.name}": collections in '
                               f'{self._collections.directory}, kinematic calibrations in '
                               f'{kinematics_dir}')
        self._description = None
        self._description_lock = threading.Lock()
        if self._p('publish_robot_description'):
            self._description = self.create_publisher(String, 'robot_description', qos.LATCHED)
            self._described = None
            self._publish_description()
            self.create_timer(DESCRIPTION_CHECK_PERIOD, self._publish_description)

    def _create_publishers(self) -> None:
        # every recorded pose, for recording a session (cobot-calib record); frame_id = target
        self._captures = self.create_publisher(CaptureMark, marks.CAPTURES, 100)
        # the live view: sphere centres and the coupling positions collected on them
        self._markers = self.create_publisher(MarkerArray, markers.TOPIC, markers.QOS)
        # every stored pose's progress and prediction, to echo, record and plot
        self._progress = self.create_publisher(CollectionProgress, 'collection_progress',
                                               qos.LATCHED)
        self._collected: list[np.ndarray] = []
        self._coupling = None if self._cell.spheres is None else Rig(
            self._cell, model=self._model).nominal_chain('coupling')

    def _declare_parameters(self) -> None:
        read_once(self, 'publish_robot_description', False,
                  'Publish the URDF of the active kinematic calibration (the cell\'s own URDF '
                  'with the identified joint origins; the nominal one while none is active) '
                  'on robot_description (latched), for robot_state_publisher, MoveIt, RViz')
        declare(self, 'hold_duration', 1.0,
                'Joints are averaged over this hold at every pose [s] (paper: 1 s at 1 kHz)',
                0.005, 10.0)
        declare(self, 'speed_scale', 1.0, 'Fraction of the joint velocity limits [1]',
                0.01, 1.0)
        declare(self, 'candidate_tilt_step', math.radians(TILT_STEP_DEG),
                'Planned collections: step of the candidate tilts, turns and arm angles on a '
                'sphere [rad] (coarser: fewer candidates to solve IK for and choose from)',
                0.05, 1.05)
        declare(self, 'max_deviation_length', MAX_DEVIATION_M,
                'Identification gate: the most a length of the model (and the tool centre) '
                'may be off nominal [m]; a result with a parameter beyond is refused, nothing '
                'stored', 1e-5, 0.1)
        declare(self, 'max_deviation_angle', MAX_DEVIATION_RAD,
                'Identification gate: the most an angle may be off nominal [rad] (a zero '
                'offset: 0.35 rad); a result with a parameter beyond is refused, nothing '
                'stored', 1e-5, 0.5)

    def _exclusive(self, goal_handle, run, Result):
        try:
            return super()._exclusive(goal_handle, run, Result)
        finally:
            self._health.set(OK, 'idle', job='')

    # -- collection -----------------------------------------------------------------------
    def _on_collect(self, goal_handle):
        return self._exclusive(goal_handle, self._collect_run, Collect.Result)

    def _collect_run(self, goal_handle):
        """Parameters in, api.kinematics.collect over RobotCalls, the result out."""
        goal, result = goal_handle.request, Collect.Result()
        self._health.set(OK, f'collecting {goal.collection_id or "a new collection"}',
                         job=goal.collection_id)
        self._robot.speed_scale = self._p('speed_scale')
        self._collected = []
        got = kinematics_api.collect(
            self._collections, self._cell, self._model, self._results_cell,
            CollectionRequest(goal.source, goal.region, goal.planned, goal.max_configs,
                              goal.max_poses, goal.target_error, goal.min_gain, goal.seed,
                              self._p('candidate_tilt_step')),
            self._robot, collection_id=goal.collection_id,
            hold=goal.hold or self._p('hold_duration'), cancelled=self._stopped(goal_handle),
            progress=self._on_pose(goal_handle), say=self.get_logger().info)
        collected = got.collected if isinstance(got, Unfinished) else got if got else None
        if collected is not None:
            result.collection_id, result.recorded = collected.collection_id, collected.recorded
            result.path = str(self._collections.directory / collected.collection_id)
            result.skipped, result.stop_reason = collected.skipped, collected.stop_reason
            result.predicted_max_error = collected.predicted_max_m
            result.robot_time = collected.time.total
            result.robot_time_at_paper_hold = collected.time.at_hold()
        if got:
            return self._end(goal_handle, result, ErrorCode.SUCCESS, got.message)
        return self._end(goal_handle, result, got.code, self._why(got))

    @staticmethod
    def _why(failure) -> str:
        """A failure's message; a collection cancelled by this node's shutdown says so."""
        if failure.code == ErrorCode.CANCELED and spin.stopping():
            return ('the kinematic_identifier node is shutting down (Ctrl-C or SIGTERM): '
                    + failure.message.replace('canceled', 'stopped', 1))
        return failure.message

    @staticmethod
    def _stopped(goal_handle):
        """A collection's ``cancelled``: the goal's cancel, or this node shutting down (its
        goal then ends aborted, the collection resumable)."""
        return lambda: goal_handle.is_cancel_requested or spin.stopping()

    def _on_pose(self, goal_handle):
        """A collection's progress: the goal's feedback, again on collection_progress, the
        capture mark and the live view's markers."""
        def on_pose(pose: PoseProgress) -> None:
            planned = pose.prediction is not None
            feedback = Collect.Feedback(
                index=pose.index, total=pose.total, target=pose.target, recorded=pose.recorded,
                skipped=pose.skipped, robot_time=pose.robot_time_s,
                predicted_max_error=pose.prediction.max_m if planned else 0.0,
                predicted_rms_error=pose.prediction.rms_m if planned else 0.0)
            self._captures.publish(marks.capture_mark(pose.target, self._model.joint_names,
                                                      pose.capture.q, pose.capture.std,
                                                      now_ns(self)))
            if pose.target != 'tracker' and self._coupling is not None:
                self._publish_markers(pose.capture.q)
            self._publish_progress(pose.collection_id, feedback, planned)
            goal_handle.publish_feedback(feedback)
        return on_pose

    def _publish_markers(self, q: np.ndarray) -> None:
        """The nominal sphere centres and the coupling at every pose so far (nominal model)."""
        self._collected.append(kinematics.fk(self._coupling, q)[:3, 3])
        self._markers.publish(markers.sphere_markers(
            self._cell.base_frame, self.get_clock().now().to_msg(), self._cell.spheres.centres_base(),
            np.array(self._collected)))

    def _publish_progress(self, collection_id: str, feedback, planned: bool) -> None:
        """A pose's collect_sphere_data feedback again, on collection_progress."""
        max_error = feedback.predicted_max_error if planned else math.inf
        self._progress.publish(CollectionProgress(
            header=Header(stamp=ns_to_stamp(now_ns(self))), collection_id=collection_id,
            target=feedback.target, planned=planned, poses=feedback.recorded,
            poses_max=feedback.total, skipped=feedback.skipped,
            predicted_max_error=max_error, predicted_max_error_mm=max_error * 1e3,
            predicted_rms_error=feedback.predicted_rms_error if planned else math.inf,
            robot_time=feedback.robot_time))

    # -- identification -------------------------------------------------------------------
    def _on_identify(self, goal_handle):
        return self._exclusive(goal_handle, self._identify_run, Identify.Result)

    def _identify_run(self, goal_handle):
        """Parameters in, api.kinematics.identify (gate, store, write-back, activate), the
        result out."""
        goal, result = goal_handle.request, Identify.Result()
        job = kinematics_api.goal_source(
            self._collections, self._cell, self._model, self._results_cell, file=goal.file,
            collection_id=goal.collection_id, objective=goal.objective or None,
            validation={'volume': goal.validation_volume,
                        'workspace': goal.validation_workspace})
        if not job:
            return self._end(goal_handle, result, job.code, job.message)
        self._health.set(OK, f'identifying from {job.source.path}', job=str(job.source.path))
        got = kinematics_api.identify(
            job, kinematics_api.Settings(
                goal.solver or 'lm', goal.loss or 'soft_l1', goal.objective or None,
                goal.max_configs, DeviationBounds(self._p('max_deviation_length'),
                                                  self._p('max_deviation_angle'))),
            None if goal.dry_run else self._repository().kinematics,
            cancelled=lambda: goal_handle.is_cancel_requested,
            progress=lambda i, cost, rms: goal_handle.publish_feedback(
                Identify.Feedback(iteration=i, cost=cost, rms=rms)))
        _fill(result, got)
        if not got:
            self._health.set(WARN, f'identification failed: {got.message}', job='')
            return self._end(goal_handle, result, got.code, got.message)
        if got.saved is not None and self._description is not None:
            self._publish_description()
        return self._end(goal_handle, result, ErrorCode.SUCCESS, got.message)

    def _publish_description(self) -> None:
        """robot_description from the active calibration, again whenever that changes (a new
        identification here, or one stored or retired by another process with the same data:
        `cobot-calib identify --source FILE`). One caller at a time: the timer's check and the
        end of an identification (its thread)."""
        with self._description_lock:
            self._describe()

    def _describe(self) -> None:
        try:
            calibrations = self._repository().kinematics   # read afresh: other writers
            active = calibrations.active(self._model.name)
        except OSError as e:
            self.get_logger().warning(f'robot_description: cannot read the active kinematic '
                                      f'calibration: {e}', throttle_duration_sec=60.0)
            return
        key = active['id'] if active is not None else ''
        if key == self._described:
            return
        if active is not None:
            path = calibrations.directory / f'{key}.urdf'
            try:
                text, what = path.read_text(), f'kinematic calibration {key} ({path})'
            except OSError as e:
                # not marked as described: tried again at the next check. (The timer's check
                # can see a new record as the newest while the identification still writes
                # its URDF: a fresh-clone run's robot_description then stayed nominal.)
                self.get_logger().warning(f'robot_description: {e}; not published yet, '
                                          'trying again in '
                                          f'{DESCRIPTION_CHECK_PERIOD:g} s',
                                          throttle_duration_sec=60.0)
                return
        elif self._cell.urdf_robot is not None and self._cell.urdf_robot.urdf:
            text = self._cell.urdf_robot.urdf
            what = f'the nominal URDF {self._cell.urdf_robot.urdf_file} (no calibration active)'
        else:
            self.get_logger().warning(
                f'robot_description: no kinematic calibration active and cell '
                f'"{self._cell.name}" gives no URDF (robot: {{urdf: ...}}); not published')
            self._described = key       # said once
            return
        self._description.publish(String(data=text))
        self._described = key
        self.get_logger().info(f'robot_description: {what}')

def _fill(result, got) -> None:
    """An IdentifyKinematics result's figures from an api.kinematics.identify answer (SI)."""
    outcome = got.outcome if isinstance(got, (Identified, GateRefused)) else None
    if outcome is None:
        return
    r = outcome.result
    result.parameter_names = list(r.free)
    result.values = [float(v) for v in outcome.free_values]
    result.nominal_values = [float(v) for v in outcome.nominal_values]
    result.std = [float(v) for v in r.std]
    result.dropped_parameters = [d.name for d in outcome.identifiability.dropped]
    result.dropped_reasons = [d.reason for d in outcome.identifiability.dropped]
    for key, nominal, calibrated in (('volume', 'validation_nominal', 'validation_calibrated'),
                                     ('workspace', 'workspace_nominal', 'workspace_calibrated')):
        table = outcome.validation.get(key)
        if table:
            setattr(result, nominal, _stats_msg(table['nominal']))
            setattr(result, calibrated, _stats_msg(table['calibrated']))
    result.rms, result.iterations = float(r.rms_m), int(r.iterations)
    result.solve_seconds = float(r.solve_seconds)
    if isinstance(got, Identified) and got.saved is not None:
        result.calibration_id = got.saved.record.id
        result.yaml_path = str(got.saved.paths['yaml'])
        result.urdf_path = str(got.saved.paths['urdf'])


def _stats_msg(stats: dict) -> ErrorStats:
    """Table 5 statistics (core.kinematics.identification.validation.error_stats) [m]."""
    return ErrorStats(count=int(stats['count']), mean=stats['mean_m'], std=stats['std_m'],
                      min=stats['min_m'], max=stats['max_m'])


def main(args=None) -> None:
    # every pose hands over between the job thread and the companion four times; with the
    # default 5 ms GIL switch interval a hand-over can wait that long (move_to 35 -> 29 ms a
    # pose measured)
    sys.setswitchinterval(0.0005)
    spin.run(KinematicIdentifier, args, threads=2)


if __name__ == '__main__':
    main()
