"""repeatability_trial: the ISO 9283 trial action (run_trial) and the live `repeatability` topic.

The procedure is core/repeatability/trial.py; this node gives it core.repeatability.trial's
PortRobot over the ROS ports (ros.robot_calls: move_to, capture_joints, probe/average, a touch
by the operator or the mock's hand_guide; for the landmark methods the wrist camera's
``landmarks`` through ros.landmark_watch, with the active hand-eye calibration, each view's
capture marked by ros.landmark_views.CaptureMarks), stores readings through
store.trials, and publishes the running statistics after every cycle (on start-up: those of
the latest stored trial). Goal semantics are in RunTrial.action. Health on /diagnostics: OK
idle, OK running (cycle figures), WARN after a failed trial (its message) until the next one
starts.
"""
from __future__ import annotations

from dataclasses import replace
import threading

from cobot_calib_msgs.action import RunTrial
from cobot_calib_msgs.msg import Repeatability
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup

from cobot_calib_ros.core.errors import ErrorCode, Failure, first_failure
from cobot_calib_ros.core.repeatability import trial as trialmod
from cobot_calib_ros.core.repeatability import PointStats
from cobot_calib_ros.core.landmarks.views import setup_problem
from cobot_calib_ros.core.robot_port import PortError
from cobot_calib_ros.nodes.job_node import JobNode
from cobot_calib_ros.store.files import check_id
from cobot_calib_ros.store.records import TrialSetup
from cobot_calib_ros.ros import qos, spin
from cobot_calib_ros.ros.diagnostics import OK, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.landmark_views import CaptureMarks
from cobot_calib_ros.ros.landmark_watch import LandmarkWatch
from cobot_calib_ros.ros.robot_calls import RobotCalls
from cobot_calib_ros.ros.time import now_ns

HEARTBEAT = 2.0         # [s] feedback at least this often while a trial runs (see RunTrial)


def store_failure(directory, error: OSError) -> Failure:
    """A trial store that cannot be written (disk full, no permission): STORAGE_FAILED, and
    what to do; the trial is resumable from what was stored."""
    return Failure(ErrorCode.STORAGE_FAILED, f'trial store {directory}: {error}; free space '
                   'or give this node write access there, then resume the trial')


def stats_msg(trial_id: str, meta: dict, cycles_done: int, stats: PointStats | None,
              stamp) -> Repeatability:
    """The trial's method, axis and cycle counts, and its statistics when there are some."""
    msg = Repeatability(trial_id=trial_id, method=meta['method'], axis=meta['axis'],
                        cycles_done=cycles_done, cycles_total=meta['cycles_total'],
                        point_names=list(meta['point_names']))
    msg.header.stamp = stamp
    if stats is None:
        msg.rp_all = msg.rp_all_mm = float('nan')
        return msg
    msg.mean_distance = stats.mean_distance.tolist()
    msg.mean_deviation = stats.mean_deviation.tolist()
    msg.sigma = stats.sigma.tolist()
    msg.rp = stats.rp.tolist()
    msg.rp_all = float(stats.rp_all)
    msg.rp_mm = (stats.rp * 1e3).tolist()
    msg.rp_all_mm = float(stats.rp_all * 1e3)
    return msg


def trial_line(trial_id: str, meta: dict) -> str:
    """'trial <id> (rigid, z axis, 30 cycles)', the subject of every log line about a trial."""
    return f'trial {trial_id} ({trialmod.describe(meta)})'


class RepeatabilityTrial(JobNode):
    def __init__(self, **kwargs) -> None:
        super().__init__('repeatability_trial', job='a trial',
                         cell_help='Cell YAML (path or name): markers, layouts, nominal tool',
                         layout_help='Marker layout (close | wide); empty = the cell default',
                         data_help='Trials go to <data_dir>/trials', **kwargs)
        self._declare_parameters()
        self._store = self._repository().trials
        self._calls = RobotCalls(self._answers, self._p('speed_scale'),
                                 probe_window=self._p('probe_window'), operator=self.get_name())
        self._camera = None if setup_problem(self._cell) is not None else LandmarkWatch(
            lambda: now_ns(self), self._answers.node)
        self._marks = CaptureMarks(self._answers.node, self._model.joint_names)
        self._pub = self.create_publisher(Repeatability, 'repeatability', qos.LATCHED)
        self._health.watch(capture_retries=lambda: self._calls.capture_retries,
                           probe_retries=lambda: self._calls.probe_retries)
        self._health.set(OK, 'idle', trial_id='', method='', axis='', cycles_done=0,
                         cycles_total=0, rp_all_mm='nan')      # the keys while running
        self._feedback_lock = threading.Lock()
        self._live = None           # (goal handle, its latest feedback) while a trial runs
        self.create_timer(HEARTBEAT, self._heartbeat)
        self._action = ActionServer(
            self, RunTrial, 'run_trial', execute_callback=self._execute,
            goal_callback=self._accept, cancel_callback=lambda _: CancelResponse.ACCEPT,
            callback_group=ReentrantCallbackGroup())
        self.get_logger().info(f'trials in {self._store.directory}, layout {self._cell.layout}')
        # once spinning: a stop right after start then takes the executor's clean way out
        self._republish = self.create_timer(0.0, self._republish_latest)

    def _declare_parameters(self) -> None:
        read_once(self, 'probe_window', 0.02, 'Probe averaging window per reading [s]',
                  0.005, 10.0)
        read_once(self, 'capture_duration', 0.3, 'Hold window when teaching a point [s]',
                  0.01, 10.0)
        read_once(self, 'speed_scale', 1.0,
                  'Fraction of the joint velocity limits for trial moves [1]', 0.01, 1.0)
        declare(self, 'kinematics', 'latest', 'Kinematic model of new trials (a resumed one '
                'keeps its own): latest (the active kinematic calibration, nominal if none), '
                'nominal, or a kinematic calibration id')
        declare(self, 'approach_distance', 0.005,
                'Retreat along the probe axis before every arrival (unidirectional) [m]',
                0.0, 0.1)

    def _republish_latest(self) -> None:
        """The latched statistics of the trial whose status changed last (done or not), as
        they were before this node (re)started; once, on start-up."""
        self._republish.cancel()
        for meta in sorted(self._store.list_trials(), key=lambda m: m['updated_ns'],
                           reverse=True):
            if self._foreign(meta) is not None:
                continue
            data = self._store.load(meta['id'])
            if data is None:
                continue
            stats = trialmod.statistics(data)
            self._pub.publish(stats_msg(meta['id'], data.meta, stats.cycles, stats,
                                        self.get_clock().now().to_msg()))
            self.get_logger().info(f'republished {trial_line(meta["id"], data.meta)}: '
                                   f'{meta["status"]}, {stats.cycles} cycles measured')
            break
        for warning in self._store.warnings:
            self.get_logger().warning(warning)

    # -- goals ----------------------------------------------------------------------------
    def _accept(self, goal) -> GoalResponse:
        """Reject what needs no store to judge (a rejected goal carries no message, so the
        client checks the same with the same core functions first); log why. Then JobNode's
        rule: one job at a time."""
        why = self._goal_problem(goal)
        if why is not None:
            self.get_logger().warning(f'run_trial goal rejected: {why.message}')
            return GoalResponse.REJECT
        return super()._accept(goal)

    def _goal_problem(self, goal) -> Failure | None:
        problem = trialmod.goal_problem(goal.method, goal.axis, goal.cycles)
        if problem is not None or not goal.trial_id:
            return problem
        try:
            check_id(goal.trial_id)
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, f'trial_id: {e}')
        return None

    def _execute(self, goal_handle):
        return self._exclusive(goal_handle, self._run, RunTrial.Result)

    def _send_feedback(self, goal_handle, feedback=None) -> None:
        """Publish ``feedback`` and keep it for the heartbeat; None: the goal is ending."""
        with self._feedback_lock:
            self._live = None if goal_handle is None else (goal_handle, feedback)
            if goal_handle is not None:
                goal_handle.publish_feedback(feedback)

    def _heartbeat(self) -> None:
        """The latest feedback again, so a client hears the node is alive during long steps
        (teaching by hand, a slow move) and can tell a hung or dead node by silence."""
        with self._feedback_lock:
            if self._live is not None:
                self._live[0].publish_feedback(self._live[1])

    def _run(self, goal_handle):
        trial = _Goal(goal_handle.request, self._calls.retries())
        try:
            run, resume = self._prepare(trial, goal_handle)
            data = run.resume(resume) if resume is not None else run.start()
        except trialmod.TrialError as e:
            return self._failed(goal_handle, trial, e.failure)
        except OSError as e:
            return self._failed(goal_handle, trial, store_failure(self._store.directory, e))
        except ValueError as e:                   # a stored trial that does not read back
            return self._failed(goal_handle, trial, Failure(
                ErrorCode.INVALID_INPUT, f'trial store {self._store.directory}: {e}'))
        finally:
            self._send_feedback(None)
        return self._succeeded(goal_handle, trial, data)

    def _failed(self, goal_handle, trial: _Goal, failure: Failure):
        """The goal's end through JobNode._end; a cancelled trial is resumable, so the node
        stays OK (idle) and says how to resume it."""
        self._send_feedback(None)
        self._end(goal_handle, result := self._result(trial), failure.code, failure.message)
        if failure.code == ErrorCode.CANCELED:
            subject = (trial_line(trial.trial_id, trial.meta) if trial.meta
                       else f'trial {trial.trial_id}')
            cycle = trial.progress[0] + 1
            self.get_logger().info(f'{subject}: canceled in cycle {cycle}; send trial_id '
                                   f'{trial.trial_id} to resume it')
            self._health.set(OK, f'idle; {subject} stopped on request in cycle {cycle}')
        else:
            self._health.set(WARN, f'last trial {trial.trial_id} failed: {failure.message}')
        return result

    def _succeeded(self, goal_handle, trial: _Goal, data):
        self._send_feedback(None)
        stats = trialmod.statistics(data)
        message = (f'{stats.cycles} cycles, RP_all {stats.rp_all * 1e3:.4f} mm '
                   f'({data.meta["method"]}, {data.meta["axis"]} axis)')
        self._end(goal_handle, result := self._result(trial, data), ErrorCode.SUCCESS,
                  f'{trial_line(trial.trial_id, data.meta)}: done, {message}')
        self._health.set(OK, f'idle; trial {trial.trial_id} done: {message}')
        return result

    def _result(self, trial: _Goal, data=None):
        """The result with what is known of the trial: its stored method, axis, cycles, RP
        (its cause and message are JobNode._end's)."""
        result = RunTrial.Result(trial_id=trial.trial_id)
        retries = trial.retries_since(self._calls.retries())
        result.capture_retries = retries['capture_joints']
        result.probe_retries = retries['probe_average']
        trial_dir = self._store.directory / trial.trial_id
        if data is None and (trial_dir / 'trial.yaml').exists():
            data = self._store.load(trial.trial_id)
        if data is not None:
            data = self._with_retries(data, retries)
        stamp = self.get_clock().now().to_msg()
        result.calibration_seconds = float('nan')
        if data is not None:
            result.calibration_seconds = trialmod.mean_calibration_seconds(data.meta)
            stats = trialmod.statistics(data)
            result.statistics = stats_msg(trial.trial_id, data.meta, stats.cycles, stats,
                                          stamp)
            result.csv_path, result.yaml_path = (str(trial_dir / 'distances.csv'),
                                                 str(trial_dir / 'trial.yaml'))
        elif trial.meta:                         # a new trial that failed before it was stored
            result.statistics = stats_msg(trial.trial_id, trial.meta, 0, None, stamp)
        return result

    def _with_retries(self, data, retries: dict[str, int]):
        """The trial with this goal's retries added to its stored ``retries``."""
        try:
            return replace(data, meta=self._store.record_retries(data.meta['id'], retries))
        except (OSError, ValueError) as e:
            self.get_logger().warning(f'trial {data.meta["id"]}: retries not stored: {e}')
            return data

    def _prepare(self, trial: _Goal, goal_handle) -> tuple[trialmod.TrialRun, object]:
        goal = trial.goal
        try:
            self._cell.require('a repeatability trial', 'layouts')
        except ValueError as e:
            raise trialmod.TrialError(ErrorCode.INVALID_INPUT, str(e)) from None
        if goal.layout and goal.layout != self._cell.layout:
            raise trialmod.TrialError(ErrorCode.INVALID_INPUT, (
                f'layout {goal.layout!r} requested but this node (and the markers) use '
                f'{self._cell.layout!r}; start the suite with layout:={goal.layout}'))
        resume = self._stored(trial)
        feedback = RunTrial.Feedback(resumed=trial.resumed)
        self._announce(trial, goal_handle, resume, feedback)
        why = self._calls.missing()
        if why:
            raise trialmod.TrialError(ErrorCode.MOTION_FAILED, why)
        robot, model_used = self._robot(trial.meta.get('kinematics') or self._p('kinematics'),
                                        lambda: goal_handle.is_cancel_requested)
        try:
            probe = trialmod.ProbeRange(*self._calls.probe_range())
        except PortError as e:
            raise trialmod.TrialError(ErrorCode.PROBE_FAILED, str(e))
        plan = trialmod.Plan(
            trial.trial_id, trial.meta['method'], trial.meta['axis'], self._cell.layout,
            [self._cell.marker(n) for n in trial.meta['point_names']],
            trial.meta['cycles_total'], probe, approach_distance=self._p('approach_distance'),
            extra={'kinematics': model_used, 'cell': self._results_cell.name,
                   'robot': self._results_cell.robot})
        run = trialmod.TrialRun(plan, robot, self._store,
                                *self._callbacks(trial, goal_handle, feedback),
                                lambda: goal_handle.is_cancel_requested)
        self._started(trial, resume)
        return run, resume

    def _robot(self, choice: str, cancelled) -> tuple[trialmod.PortRobot, str]:
        """The trial's robot on the chain of a kinematics choice (landmark views: with the
        active hand-eye as the camera's tool); the choice's label (id or nominal)."""
        try:
            rig = self._rig(choice)
            views = None if self._camera is None else trialmod.LandmarkRig(
                self._camera, self._cell, rig.nominal_chain('camera'), rig.chain('camera'),
                self._marks)
        except (KeyError, ValueError) as e:
            raise trialmod.TrialError(ErrorCode.INVALID_INPUT,
                                      f'kinematics {choice!r}: {e}; use latest, '
                                      'nominal or a stored kinematic calibration id')
        robot = trialmod.PortRobot(self._calls, rig.chain('tcp'), self._cell.home,
                                   self._p('capture_duration'), views, cancelled)
        return robot, rig.active.kinematics_label

    def _stored(self, trial: _Goal):
        """The stored trial this goal resumes (None for a new one); fills ``trial.meta``."""
        goal = trial.goal
        exists = (self._store.directory / trial.trial_id).exists()
        stored = self._store.load(trial.trial_id) if exists else None
        if exists and stored is None:
            raise trialmod.TrialError(ErrorCode.INVALID_INPUT, (
                f'trial {trial.trial_id} is stored but unreadable '
                f'({self._store.meta_problem(trial.trial_id)}); pick a new trial_id'))
        if stored is None:
            trial.meta = TrialSetup(method=goal.method or trialmod.DEFAULT_METHOD,
                                    axis=goal.axis or trialmod.DEFAULT_AXIS,
                                    cycles_total=goal.cycles or trialmod.DEFAULT_CYCLES,
                                    point_names=self._cell.point_names).to_dict()
            return None
        foreign = self._foreign(stored.meta)
        if foreign is not None:
            raise trialmod.TrialError(foreign.code, (
                f'trial {trial.trial_id} is not this cell\'s: {foreign.message}; resume it on '
                'its own cell\'s suite, or leave the trial id out to start a new trial'))
        trial.meta = stored.meta
        problem = first_failure(
            trialmod.resume_problem(stored.meta, goal.method, goal.axis, goal.cycles),
            self._layout_problem(stored.meta))
        if problem is not None:
            raise trialmod.TrialError(problem.code, problem.message)
        if stored.resume is None:
            raise trialmod.TrialError(ErrorCode.INVALID_INPUT, (
                f'trial {trial.trial_id} ({trialmod.describe(stored.meta)}) is complete; '
                'pick a new trial_id (empty = a fresh one)'))
        trial.progress, trial.resumed = stored.resume, True
        return stored

    def _layout_problem(self, meta: dict) -> Failure | None:
        if meta['layout'] == self._cell.layout:
            return None
        return Failure(ErrorCode.INVALID_INPUT,
                       f'trial {meta["id"]} was measured on the {meta["layout"]} layout, this '
                       f'node uses {self._cell.layout}; start the suite with '
                       f'layout:={meta["layout"]} to resume it')

    def _announce(self, trial: _Goal, goal_handle, resume, feedback) -> None:
        """The first feedback, before waiting for the robot: what runs (for a resume: the
        stored method, axis and cycles); every feedback carries that from here on."""
        stats = trialmod.statistics(resume) if resume is not None else None
        feedback.cycle, feedback.distance = trial.progress[0], float('nan')
        feedback.statistics = stats_msg(trial.trial_id, trial.meta,
                                        stats.cycles if stats is not None else 0, stats,
                                        self.get_clock().now().to_msg())
        self._send_feedback(goal_handle, feedback)

    def _started(self, trial: _Goal, resume) -> None:
        """Log the start or resume (the robot is ready, the plan checked), set the health."""
        subject, cycle = trial_line(trial.trial_id, trial.meta), trial.progress[0]
        stats = trialmod.statistics(resume) if resume is not None else None
        done = stats.cycles if stats is not None else 0
        if resume is None:
            self.get_logger().info(f'{subject}: start')
        else:
            self.get_logger().info(f'{subject}: resume at cycle {cycle + 1} '
                                   f'({done} complete cycles stored)')
        self._running(trial, done, stats)

    def _running(self, trial: _Goal, cycles_done: int, stats: PointStats | None) -> None:
        rp = stats.rp_all * 1e3 if stats is not None else float('nan')
        total = trial.meta['cycles_total']
        self._health.set(OK, f'running trial {trial.trial_id}: {cycles_done}/{total} cycles, '
                         f'RP_all {rp:.4f} mm', trial_id=trial.trial_id,
                         method=trial.meta['method'], axis=trial.meta['axis'],
                         cycles_done=cycles_done, cycles_total=total, rp_all_mm=f'{rp:.4f}')

    def _callbacks(self, trial: _Goal, goal_handle, feedback):
        """TrialRun's on_reading and on_cycle: feedback, the topic, the health."""
        names = trial.meta['point_names']

        def on_reading(cycle: int, i: int, distance: float) -> None:
            trial.progress = (cycle, i)
            with self._feedback_lock:
                feedback.cycle, feedback.point_index = cycle, i
                feedback.point_name, feedback.distance = names[i], distance
            self._send_feedback(goal_handle, feedback)

        def on_cycle(cycles_done: int, stats: PointStats) -> None:
            msg = stats_msg(trial.trial_id, trial.meta, cycles_done, stats,
                            self.get_clock().now().to_msg())
            self._pub.publish(msg)
            with self._feedback_lock:
                feedback.statistics = msg
            self._send_feedback(goal_handle, feedback)
            self._running(trial, cycles_done, stats)
        return on_reading, on_cycle


class _Goal:
    """One run_trial goal as it is worked out: its id, the trial's metadata once known (the
    stored one on resume), and the (cycle, point) reached."""

    def __init__(self, goal, retries: dict[str, int]) -> None:
        self.goal = goal
        self._retries_before = retries      # the node's retry counts when the goal came
        self.trial_id = goal.trial_id or trialmod.new_trial_id(goal.method, goal.axis)
        self.meta: dict = {}
        self.progress: tuple[int, int] = (0, 0)
        self.resumed = False

    def retries_since(self, retries: dict[str, int]) -> dict[str, int]:
        """The retries this goal made (the node's counts now minus those at its start)."""
        return {k: n - self._retries_before.get(k, 0) for k, n in retries.items()}


def main(args=None) -> None:
    spin.run(RepeatabilityTrial, args, threads=2)


if __name__ == '__main__':
    main()
