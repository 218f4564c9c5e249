"""kinematic_identifier: sphere-coupling data collection and kinematic identification.

Two actions, one long job at a time (the node spins two threads: one runs the job, the other
answers cancels and feedback):

- ``collect_sphere_data``: the second paper's Algorithm 2 through ``move_to`` (compliant: the
  coupling self-centres on the sphere) and ``capture_joints``, or laser-tracker configurations
  through ``laser_tracker/measure``; every pose is stored as it is measured and a collection
  resumes after a restart. ``planned``: each sphere pose is chosen with the data so far
  (core.kinematics.planning), with a predicted accuracy and a stopping rule.
- ``identify_kinematics``: the one identification engine (core.kinematics.kinematic_calibration:
  the data as measurements, identifiability, Levenberg-Marquardt or Nelder-Mead, the gates),
  validation on laser-tracker collections, stored as JSON + YAML + calibrated URDF and made
  the active kinematic calibration that user_frame_solver and repeatability_trial use.
"""
from __future__ import annotations

import math
import sys
from time import monotonic

from cobot_calib_msgs.action import CollectSphereData, IdentifyKinematics
from cobot_calib_msgs.msg import CaptureMark, CollectionProgress, ErrorStats
import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from std_msgs.msg import Header, String
from visualization_msgs.msg import MarkerArray

from cobot_calib_ros.core import kinematics
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.collection import collect, Ending, PoseRecord
from cobot_calib_ros.core.kinematics.planned_collection import collect_planned, RobotTime
from cobot_calib_ros.core.kinematics.planning import (PlanSettings, Prediction,
                                                      sphere_candidates, SpherePlanner,
                                                      tilt_grid_deg, TILT_STEP_DEG,
                                                      too_few_poses)
from cobot_calib_ros.core.kinematics.identification.measurement_fit import LOSSES, SOLVERS
from cobot_calib_ros.core.kinematics.identification.gates import (
    DeviationBounds, MAX_DEVIATION_M, MAX_DEVIATION_RAD)
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob, JobCancelled
from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.core.rig import Rig
from cobot_calib_ros.loaders import sources
from cobot_calib_ros.ros import markers, marks, qos, spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns, ns_to_stamp
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.store.files import check_id

Collect, Identify = CollectSphereData, IdentifyKinematics
PLANNED_MAX_POSES = 50
DESCRIPTION_CHECK_PERIOD = 2.0   # [s] between looks at the active calibration (robot_description)
PLANNING_TASK_SEED = 1      # the task volume's configurations (the validation set is seed 0)


class KinematicIdentifier(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('kinematic_identifier', job='a collection or identification',
                         cell_help='Cell YAML (path or name): robot, home, the sphere plate '
                         'and coupling', data_help='Collections go to <data_dir>/kinematic_data, '
                         'results to <data_dir>/kinematics', **kwargs)
        self._declare_parameters()
        repository = self._repository()
        self._collections = repository.collections
        self._calibrations = repository.kinematics
        self._robot = RobotCalls(self._answers)
        self._health.watch(capture_retries=lambda: self._robot.capture_retries)
        self._health.set(OK, 'idle', job='')
        # every recorded pose, for recording a session (cobot-calib record); frame_id = target
        self._captures = self.create_publisher(CaptureMark, marks.CAPTURES, 100)
        # the live view: sphere centres and the coupling positions collected on them
        self._markers = self.create_publisher(MarkerArray, markers.TOPIC, markers.QOS)
        # every stored pose's progress and prediction, to echo, record and plot
        self._progress = self.create_publisher(CollectionProgress, 'collection_progress',
                                               qos.LATCHED)
        self._collected: list[np.ndarray] = []
        spheres = self._cell.spheres
        self._coupling = None if spheres is None else Rig(
            self._cell, model=self._model).nominal_chain('coupling')
        group = ReentrantCallbackGroup()
        self._collect = ActionServer(
            self, Collect, 'collect_sphere_data', execute_callback=self._on_collect,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group)
        self._identify = ActionServer(
            self, Identify, 'identify_kinematics', execute_callback=self._on_identify,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=group)
        self.get_logger().info(f'{self._cell.robot} cell "{self._cell.name}": collections in '
                               f'{self._collections.directory}, kinematic calibrations in '
                               f'{self._calibrations.directory}')
        self._description = None
        if self._p('publish_robot_description'):
            self._description = self.create_publisher(String, 'robot_description', qos.LATCHED)
            self._described = None
            self._publish_description()
            self.create_timer(DESCRIPTION_CHECK_PERIOD, self._publish_description)

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
                'Planned collections: step of the candidate tilts on a sphere [rad] (coarser: '
                'fewer candidates to solve IK for and choose from, longer moves)', 0.05, 1.05)
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
        goal, result = goal_handle.request, Collect.Result()
        try:
            collection_id, meta = self._open_collection(goal)
        except ValueError as e:
            return self._end(goal_handle, result, ErrorCode.INVALID_INPUT, str(e))
        except OSError as e:
            return self._end(goal_handle, result, ErrorCode.STORAGE_FAILED,
                             f'could not store the collection: {e}; check data_dir')
        result.collection_id = collection_id
        result.path = str(self._collections.directory / collection_id)
        hold = goal.hold or self._p('hold_duration')
        self._health.set(OK, f'collecting {collection_id}', job=collection_id)
        visit = self._visit_planned if 'planning' in meta else self._visit
        # the visit counts the poses into result: no reading back of the collection (its
        # plan's YAML, 0.1 s quiet, took most of a stopping node's 3 s grace at load)
        code, message, time = visit(goal_handle, collection_id, meta, hold, result)
        result.robot_time, result.robot_time_at_paper_hold = time.total, time.at_hold()
        status = 'done' if code == ErrorCode.SUCCESS else 'aborted'
        try:
            self._collections.set_status(collection_id, status)
        except (OSError, ValueError) as e:
            code, message = ErrorCode.STORAGE_FAILED, f'could not store the status: {e}'
        if code == ErrorCode.SUCCESS:
            message = (f'{collection_id}: {result.recorded} poses recorded, '
                       f'{result.skipped} skipped ({message}); robot time '
                       f'{time.total:.1f} s ({time.at_hold():.1f} s at a 1 s hold)')
        return self._end(goal_handle, result, code, message)

    def _open_collection(self, goal) -> tuple[str, dict]:
        """A stored unfinished collection to resume, or a new one with its plan stored."""
        if goal.collection_id:
            check_id(goal.collection_id)
            stored = self._collections.load(goal.collection_id)
            if stored is not None:
                meta = stored.meta
                foreign = self._foreign(meta)
                if foreign:
                    raise ValueError(f'collection {goal.collection_id} is not this cell\'s: '
                                     f'{foreign}; resume it on its own cell\'s suite, or '
                                     'give a new id (or none)')
                if meta['status'] == 'done':
                    raise ValueError(f'collection {goal.collection_id} is complete; give a '
                                     'new id (or none) to collect again')
                self._collections.set_status(goal.collection_id, 'running')
                return goal.collection_id, meta
        source = goal.source or 'spheres'
        region = goal.region or 'volume'
        if goal.planned and source != 'spheres':
            raise ValueError('planned applies to source spheres only')
        if goal.planned:        # refused in a second, before the candidate IK and any move
            problem = too_few_poses(self._cell, self._model,
                                    goal.max_poses or PLANNED_MAX_POSES)
            if problem:
                raise ValueError(problem)
        if source == 'spheres':
            if goal.planned:
                step_deg = math.degrees(self._p('candidate_tilt_step'))
                self.get_logger().info(f'planned collection: solving IK for the candidate '
                                       f'poses (tilts in {step_deg:.4g} deg steps)')
                started = monotonic()
                plan, unreachable = sphere_candidates(self._cell, self._model,
                                                      tilt_grid_deg(step_deg))
                self.get_logger().info(f'{len(plan)} candidates reachable, '
                                       f'{len(unreachable)} not, in '
                                       f'{monotonic() - started:.1f} s')
            else:
                plan, unreachable = plans.sphere_plan(self._cell, self._model,
                                                      goal.max_configs)
            targets = list(self._cell.spheres.names)
            extra = {'known_distances': self._cell.spheres.known_distances(),
                     'unreachable_in_plan': unreachable,
                     'coupling_offset_xyz': self._cell.spheres.coupling_offset[:3, 3]}
            if goal.planned:
                extra['planning'] = self._planning(goal)
        elif source == 'laser_tracker':
            plan = plans.tracker_plan(self._cell, self._model, region,
                                      goal.max_configs or plans.TRACKER_CONFIGS, goal.seed)
            targets, extra = [], {'region': region, 'seed': goal.seed,
                                  'coupling_offset_xyz': self._cell.spheres.coupling_offset[:3, 3]}
        else:
            raise ValueError(f'unknown source {source!r}; use spheres or laser_tracker')
        collection_id = goal.collection_id or record_id(
            source if source == 'spheres' else f'tracker-{region}')
        meta = self._collections.create(
            collection_id, source=source, robot=self._cell.robot,
            joint_names=self._model.joint_names, targets=targets, plan=plan,
            extra={**extra, 'cell': self._results_cell.name})
        return collection_id, meta

    def _planning(self, goal) -> dict:
        """A new planned collection's settings and task-volume configurations (stored: a
        resume plans with the same)."""
        settings = PlanSettings(max_poses=goal.max_poses or PLANNED_MAX_POSES,
                                target_mm=goal.target_error * 1e3, min_gain=goal.min_gain)
        task = plans.tracker_plan(self._cell, self._model, 'volume', plans.TRACKER_CONFIGS,
                                  PLANNING_TASK_SEED)
        return {'settings': vars(settings), 'task_q': [step['q'] for step in task]}

    def _visit_planned(self, goal_handle, collection_id: str, meta: dict, hold: float,
                       result) -> tuple[int, str, RobotTime]:
        """The planned collection (core.kinematics.planned_collection over RobotCalls), from
        the poses stored so far; its planning state stored at the end; (code, message, time)."""
        planning = meta['planning']
        planner = SpherePlanner(self._model, meta['plan'], meta['known_distances'],
                                meta['coupling_offset_xyz'], planning['task_q'],
                                PlanSettings(**planning['settings']))
        stored = self._collections.load(collection_id)
        planner.resume(stored.index.tolist(), stored.q, list(stored.skipped))
        before = planning.get('state')
        if before:          # a resumed collection keeps the plan made before the robot moved
            planner.state.initial_plan = before['initial_plan']
            planner.state.initial_predictions = [Prediction.from_dict(p)
                                                 for p in before['initial_predictions']]
        else:
            planner.start()
        feedback = Collect.Feedback(total=planner.settings.max_poses)
        start = self._robot.robot_seconds
        self._collected = []

        def on_pose(record, capture, run, prediction) -> None:
            feedback.index, feedback.recorded = len(planner.q) - 1, len(planner.q)
            feedback.target = meta['targets'][record.target]
            feedback.skipped = len(planner.state.skipped)
            feedback.predicted_max_error = prediction.max_mm * 1e-3
            feedback.predicted_rms_error = prediction.rms_mm * 1e-3
            feedback.robot_time = self._robot.robot_seconds - start
            self._publish_capture(feedback.target, capture)
            if self._coupling is not None:
                self._publish_markers(capture.q)
            self._publish_progress(collection_id, feedback, feedback.recorded, planned=True)
            goal_handle.publish_feedback(feedback)

        self._robot.speed_scale = self._p('speed_scale')
        run, time = collect_planned(planner, self._robot, self._store(collection_id),
                                    hold=hold, on_pose=on_pose,
                                    cancelled=self._stopped(goal_handle))
        result.recorded, result.skipped = len(planner.q), len(planner.state.skipped)
        last = planner.state.predictions[-1] if planner.state.predictions else None
        result.stop_reason = planner.state.stop or ''
        result.predicted_max_error = last.max_mm * 1e-3 if last else float('inf')
        done = planning.get('robot_time', {})
        total = RobotTime(time.move + done.get('move_s', 0.0),
                          time.hold + done.get('hold_s', 0.0),
                          time.poses + int(done.get('poses', 0)))
        try:
            self._collections.update(collection_id, planning={
                **planning, 'state': planner.state.as_dict(), 'robot_time': total.as_dict()})
        except OSError as e:
            return (ErrorCode.STORAGE_FAILED,
                    f'{collection_id}: could not store the planning: {e}; check data_dir', time)
        if run.ending is Ending.DONE:
            return ErrorCode.SUCCESS, f'stopped on {run.message}', time
        return (*self._ended(run, collection_id), time)

    def _store(self, collection_id: str):
        def store(record: PoseRecord) -> None:
            self._collections.append(collection_id, record.index, record.target, record.q,
                                     sample_count=record.sample_count, std_max=record.std_max,
                                     p=record.p, note=record.note)
        return store

    @staticmethod
    def _stopped(goal_handle):
        """A collection's ``cancelled``: the goal's cancel, or this node shutting down (its
        goal then ends aborted, the collection resumable)."""
        return lambda: goal_handle.is_cancel_requested or spin.stopping()

    @staticmethod
    def _ended(run, collection_id: str) -> tuple[ErrorCode, str]:
        code = {Ending.CANCELED: ErrorCode.CANCELED,
                Ending.MOTION_FAILED: ErrorCode.MOTION_FAILED,
                Ending.CAPTURE_FAILED: ErrorCode.CAPTURE_FAILED}[run.ending]
        why = run.message
        if run.ending is Ending.CANCELED and spin.stopping():
            why = ('the kinematic_identifier node is shutting down (Ctrl-C or SIGTERM): '
                   + why.replace('canceled', 'stopped', 1))
        return code, f'{collection_id}: {why}; give the same collection_id to resume'

    def _visit(self, goal_handle, collection_id: str, meta: dict, hold: float,
               result) -> tuple[int, str, RobotTime]:
        """Visit the plan from the first pose without a row (core.kinematics.collection over
        RobotCalls, the robot port); (code, message, robot time)."""
        plan, laser = meta['plan'], meta['source'] == 'laser_tracker'
        feedback = Collect.Feedback(total=len(plan))
        start = self._robot.robot_seconds

        self._collected = []

        def on_pose(record, capture, run) -> None:
            feedback.index = record.index
            feedback.target = 'tracker' if laser else meta['targets'][record.target]
            self._publish_capture(feedback.target, capture)
            if not laser and self._coupling is not None:
                self._publish_markers(capture.q)
            # the collection's poses, as the result counts them (a resume goes on counting)
            feedback.recorded = before + run.recorded
            feedback.skipped = skipped_before + run.skipped
            feedback.robot_time = self._robot.robot_seconds - start
            self._publish_progress(collection_id, feedback, feedback.recorded)
            goal_handle.publish_feedback(feedback)

        self._robot.speed_scale = self._p('speed_scale')
        stored = self._collections.load(collection_id)
        before, skipped_before = len(stored.index), len(stored.skipped)
        run = collect(plan, stored.next_index, self._robot,
                      self._store(collection_id), hold=hold, laser=laser,
                      cancelled=self._stopped(goal_handle), on_pose=on_pose)
        result.recorded = before + run.recorded
        result.skipped = skipped_before + run.skipped
        total = self._robot.robot_seconds - start
        time = RobotTime(total - run.recorded * hold, run.recorded * hold, run.recorded)
        if run.ending is Ending.DONE:
            return ErrorCode.SUCCESS, f'per pose: {run.per_pose()}', time
        return (*self._ended(run, collection_id), time)

    def _publish_markers(self, q: np.ndarray) -> None:
        """The nominal sphere centres and the coupling at every pose so far (nominal model)."""
        self._collected.append(kinematics.fk(self._coupling, q)[:3, 3])
        self._markers.publish(markers.sphere_markers(
            self._cell.base_frame, self.get_clock().now().to_msg(), self._cell.spheres.centres_base(),
            np.array(self._collected)))

    def _publish_capture(self, target: str, capture) -> None:
        self._captures.publish(marks.capture_mark(target, self._model.joint_names,
                                                  capture.q, capture.std,
                                                  now_ns(self)))

    def _publish_progress(self, collection_id: str, feedback, poses: int,
                          planned: bool = False) -> None:
        """A pose's collect_sphere_data feedback again, on collection_progress; ``poses``
        stored in the collection so far."""
        max_error = feedback.predicted_max_error if planned else math.inf
        self._progress.publish(CollectionProgress(
            header=Header(stamp=ns_to_stamp(now_ns(self))), collection_id=collection_id,
            target=feedback.target, planned=planned, poses=poses,
            poses_max=feedback.total, skipped=feedback.skipped,
            predicted_max_error=max_error, predicted_max_error_mm=max_error * 1e3,
            predicted_rms_error=feedback.predicted_rms_error if planned else math.inf,
            robot_time=feedback.robot_time))

    # -- identification -------------------------------------------------------------------
    def _on_identify(self, goal_handle):
        return self._exclusive(goal_handle, self._identify_run, Identify.Result)

    def _identify_run(self, goal_handle):
        goal, result = goal_handle.request, Identify.Result()
        try:
            job, partial, planning = self._job(goal)
        except Refusal as e:
            return self._end(goal_handle, result,
                             e.failure.code, str(e))
        except ValueError as e:
            return self._end(goal_handle, result, ErrorCode.INVALID_INPUT, str(e))
        self._health.set(OK, f'identifying from {job.source}', job=job.source)
        feedback = Identify.Feedback()

        def on_iteration(iteration: int, cost: float, rms: float) -> bool:
            feedback.iteration, feedback.cost, feedback.rms = iteration, cost, rms
            goal_handle.publish_feedback(feedback)
            return not goal_handle.is_cancel_requested

        try:
            outcome = job.run(on_iteration)
        except JobCancelled:
            return self._end(goal_handle, result, ErrorCode.CANCELED, 'canceled; '
                             'nothing stored')
        except Refusal as e:
            self._health.set(WARN, f'identification refused: {e}', job='')
            return self._end(goal_handle, result,
                             e.failure.code,
                             '; '.join(filter(None, (str(e), 'nothing stored', partial))))
        except (ValueError, np.linalg.LinAlgError) as e:
            self._health.set(WARN, f'identification failed: {e}', job='')
            return self._end(goal_handle, result, ErrorCode.SOLVER_FAILED,
                             '; '.join(filter(None, (str(e), partial))))
        self._fill(result, outcome)
        if not outcome.verdict.passed:
            self._health.set(WARN, f'identification {outcome.verdict.line()}', job='')
            return self._end(goal_handle, result,
                             ErrorCode.IMPLAUSIBLE_FIT,
                             '; '.join(filter(None, (outcome.summary(), 'nothing stored',
                                                     partial))))
        if not goal.dry_run:
            try:
                saved = self._calibrations.save_outcome(
                    outcome, extra={'planning': planning} if planning else None,
                    description=self._cell.urdf_robot)
            except (OSError, ValueError) as e:     # ValueError: the cell's URDF is not the chain
                return self._end(goal_handle, result, ErrorCode.STORAGE_FAILED,
                                 f'could not store the kinematic calibration: {e}')
            result.calibration_id = saved.record.id
            result.yaml_path, result.urdf_path = (str(saved.paths['yaml']),
                                                  str(saved.paths['urdf']))
            if self._description is not None:
                self._publish_description()
        return self._end(goal_handle, result, ErrorCode.SUCCESS,
                         '; '.join(filter(None, (outcome.summary(), partial))))

    def _publish_description(self) -> None:
        """robot_description from the active calibration, again whenever that changes (a new
        identification here, or `cobot-calib history --activate` from another process)."""
        try:
            active = self._calibrations.active(self._model.name)
        except OSError as e:
            self.get_logger().warning(f'robot_description: cannot read the active kinematic '
                                      f'calibration: {e}', throttle_duration_sec=60.0)
            return
        key = active['id'] if active is not None else ''
        if key == self._described:
            return
        self._described = key
        if active is not None:
            path = self._calibrations.directory / f'{key}.urdf'
            try:
                text, what = path.read_text(), f'kinematic calibration {key} ({path})'
            except OSError as e:
                self.get_logger().error(f'robot_description: {e}; not published')
                return
        elif self._cell.urdf_robot is not None and self._cell.urdf_robot.urdf:
            text = self._cell.urdf_robot.urdf
            what = f'the nominal URDF {self._cell.urdf_robot.urdf_file} (no calibration active)'
        else:
            self.get_logger().warning(
                f'robot_description: no kinematic calibration active and cell '
                f'"{self._cell.name}" gives no URDF (robot: {{urdf: ...}}); not published')
            return
        self._description.publish(String(data=text))
        self.get_logger().info(f'robot_description: {what}')

    def _job(self, goal) -> tuple[CalibrationJob, str, dict | None]:
        """The identification job of a goal (data, validation sets, options), '' or what
        is missing when its collection is partial, and the collection's planning (plan,
        predictions, stop reason) if it was planned."""
        planning = None
        for name, value, known in (('solver', goal.solver, SOLVERS), ('loss', goal.loss, LOSSES),
                                   ('objective', goal.objective, ('relative', 'absolute'))):
            if value and value not in known:
                raise ValueError(f'unknown {name} {value!r}; use one of {", ".join(known)}')
        if goal.file:       # a collection folder or a recorded session (its capture marks)
            source = self._file_source(goal.file)
        else:
            source = sources.of_collection(self._collection(
                goal.collection_id, 'spheres' if goal.objective != 'absolute' else
                'laser_tracker'), self._cell, self._model)
        data, partial = source.observations, source.provenance.get('partial', '')
        planning = source.provenance.get('planning')
        validation = {}
        for key, given in (('volume', goal.validation_volume),
                           ('workspace', goal.validation_workspace)):
            collection = self._collection(given, 'laser_tracker', region=key, required=False)
            if collection is not None:
                validation[key] = sources.observations(collection)
        return CalibrationJob(self._cell, self._model, data,
                              source=source.provenance.get('collection', goal.file),
                              solver=goal.solver or 'lm', loss=goal.loss or 'soft_l1',
                              objective=goal.objective or None, max_configs=goal.max_configs,
                              validation=validation,
                              bounds=DeviationBounds(self._p('max_deviation_length'),
                                                     self._p('max_deviation_angle'))), \
            partial, planning

    def _file_source(self, file: str):
        """The loaders.sources.Source of a goal's ``file``: a bag or a collection folder
        (ValueError for anything else, or one that cannot be read)."""
        kind = sources.recognise(file)
        if kind not in (sources.BAG, sources.COLLECTION):
            raise ValueError(f'{file}: a {kind} is identified offline: cobot-calib identify '
                             f'--source {file}; the goal\'s file is a bag or a collection folder')
        try:
            return sources.load_source(file, cell=self._cell)
        except BagError as e:
            raise ValueError(str(e)) from None

    def _collection(self, collection_id: str, source: str, region: str | None = None,
                    required: bool = True):
        """The given collection, else the newest done one of ``source`` (and region)."""
        if collection_id:
            data = self._collections.load(check_id(collection_id))
            if data is None:
                raise Refusal(Failure(ErrorCode.NO_DATA, f'no readable collection '
                                      f'{collection_id!r} in {self._collections.directory}'))
            foreign = self._foreign(data.meta)
            if foreign:
                raise Refusal(Failure(ErrorCode.INVALID_INPUT, (
                    f'collection {collection_id} is not this cell\'s: {foreign}; identify it '
                    'on its own cell\'s suite (or offline: cobot-calib identify --source)')))
            return data
        for meta in self._collections.list_collections():
            if meta['source'] == source and meta['status'] == 'done' and \
                    not self._foreign(meta) and (region is None or meta.get('region') == region):
                return self._collections.load(meta['id'])
        if required:
            raise Refusal(Failure(ErrorCode.NO_DATA, (
                f'no finished {source} collection for {self._cell.robot} in '
                f'{self._collections.directory}; run collect_sphere_data first')))
        return None

    @staticmethod
    def _fill(result, outcome) -> None:
        r = outcome.result
        result.parameter_names = list(r.free)
        result.values = [float(v) for v in outcome.free_values]
        result.nominal_values = [float(v) for v in outcome.nominal_values]
        result.std = [float(v) for v in r.std]
        result.dropped_parameters = [d.name for d in outcome.identifiability.dropped]
        result.dropped_reasons = [d.reason for d in outcome.identifiability.dropped]
        for key, nominal, calibrated in (('volume', 'validation_nominal',
                                          'validation_calibrated'),
                                         ('workspace', 'workspace_nominal',
                                          'workspace_calibrated')):
            table = outcome.validation.get(key)
            if table:
                setattr(result, nominal, _stats_msg(table['nominal']))
                setattr(result, calibrated, _stats_msg(table['calibrated']))
        result.rms, result.iterations = float(r.rms_m), int(r.iterations)
        result.solve_seconds = float(r.solve_seconds)


def _stats_msg(stats: dict) -> ErrorStats:
    """Table 5 statistics (mm in the core's dict) as an SI message."""
    return ErrorStats(count=int(stats['count']), mean=stats['mean_mm'] * 1e-3,
                      std=stats['std_mm'] * 1e-3, min=stats['min_mm'] * 1e-3,
                      max=stats['max_mm'] * 1e-3)


def main(args=None) -> None:
    # every pose hands over between the job thread and the companion four times; with the
    # default 5 ms GIL switch interval a hand-over can wait that long (move_to 35 -> 29 ms a
    # pose measured)
    sys.setswitchinterval(0.0005)
    spin.run(KinematicIdentifier, args, threads=2)


if __name__ == '__main__':
    main()
