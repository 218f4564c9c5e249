"""The ISO 9283 repeatability trial of the first paper (sections 2.1, 3 and 4.3), robot-agnostic.

Set-up, once per trial: every marker is touched and its robot coordinates P_i^R are read from
the encoders (nominal forward kinematics: the taught pose); then, per point and probed axis,
the offset F_i puts the probe tip where it reads the middle of its range.

Each cycle n then visits the points P1..Pm once:
- ``reference``: the robot is sent to the taught robot coordinates (plus F_i), no user frame:
  the reference repeatability of the robot itself;
- a calibration method: first a calibration pass probes the top face of every marker at its
  taught position (z offsets re-read each cycle, as the paper does), the method fits this
  cycle's frame M_n from those points, and the measurement pass sends the robot to the nominal
  user-frame points through M_n. The spread then measures how well the user frame is
  calibrated, not only the robot.
- a landmark method (``landmark_single`` / ``landmark_multi``): the calibration pass is the
  robot's own (:meth:`Robot.landmark_frame`: wrist-camera views planned around the frame the
  taught points give), then the same measurement pass through that M_n.
The robot time of each cycle's calibration pass (moves as the robot reports them, holds) is
stored with the trial as ``calibration_s`` (the paper's Figure 7 compares the methods' times).
A reading out of the probe range is retried after moving by FF_i,n (eq 15; up to
MAX_FF_STEPS times in one direction), and the stored distance is corrected for the total.

A stopped trial resumes at the start of its interrupted cycle (see :meth:`TrialRun.resume`).

Everything here is in metres and radians; the robot, the probe and the store come in as
objects (:class:`Robot`, built by :class:`PortRobot` over the core.robot_port ports), so this
runs the same on the ROS nodes and in a plain test.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
import time
from typing import Protocol, TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.core.cell import Cell, Marker, tool_down_orientation
from cobot_calib_ros.core.errors import ErrorCode, Failure, first_failure, Refusal
from cobot_calib_ros.core.landmarks import views
from cobot_calib_ros.core.landmarks.views import ViewMark
from cobot_calib_ros.core.repeatability.iso9283 import (
    AXES, point_statistics, PointStats, probe_offset, range_correction)
from cobot_calib_ros.core.robot_port import (CameraPort, Cancelled, never, PortError,
                                             RobotPort, Stopped)
from cobot_calib_ros.core.sensors.probe import Reading, ReadingStatus
from cobot_calib_ros.core.user_frame.landmarks import LANDMARK_METHODS
from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR

if TYPE_CHECKING:   # the store is passed in; core never does I/O itself
    from cobot_calib_ros.store.trials import TrialData, TrialStore

Array = NDArray[np.float64]
METHODS = ('reference', *user_frame.METHODS, *LANDMARK_METHODS)
DEFAULT_METHOD, DEFAULT_AXIS, DEFAULT_CYCLES = 'reference', 'z', 30    # for a new trial
MIN_CYCLES, MAX_CYCLES = 2, 10000    # RP needs sigma of eq (12): at least two cycles
MAX_FF_STEPS = 3     # eq (15) moves, each by FF, before a reading counts as out of reach: a
                     # single-landmark frame can be off by more than half the probe range


class TrialError(Refusal):
    """The trial cannot go on, and why (``code``: INVALID_INPUT, MOTION_FAILED, PROBE_FAILED,
    CANCELED, ...); the node answers it through ros/results.py."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(Failure(code, message))

    @property
    def code(self) -> ErrorCode:
        return self.failure.code


class Robot(Protocol):
    """What a trial needs of the cell; :class:`PortRobot` builds it over a RobotPort."""

    def touch(self, name: str) -> Array:
        """Hand-guide the tool onto a marker's top; the (4, 4) nominal tool pose read there."""

    def move(self, T_base_tool: Array) -> None:
        """Move the tool to a pose in the base frame; TrialError (MOTION_FAILED) if it cannot."""

    def read(self) -> Reading:
        """Average the probe; TrialError (PROBE_FAILED) when there is no reading.

        An out-of-range reading has status BELOW_RANGE / ABOVE_RANGE and a NaN distance."""

    def landmark_frame(self, method: str, T_base_user_guess: Array) -> Array:
        """A landmark method's (4, 4) T_base_user from wrist-camera views planned around
        ``T_base_user_guess``; TrialError (MOTION_FAILED, INVALID_INPUT, ...) when it fails."""

    robot_seconds: float
    """Robot time spent so far [s]: moves (as the robot reports them) and holds."""


@dataclass(frozen=True)
class LandmarkRig:
    """What a landmark method's frame M_n is measured with (core.landmarks.views)."""

    camera: CameraPort
    cell: Cell
    plan_chain: kinematics.Chain     # the model, its tool the hand-eye views are planned with
    chain: kinematics.Chain          # the model, its tool the hand-eye the frame is measured with
    on_view: ViewMark | None = None  # called once a view is captured (ROS: the capture mark)


class PortRobot:
    """The trial's :class:`Robot` over a core.robot_port.RobotPort, on the trial's kinematic
    model ``chain`` (nominal or calibrated; its tool: the probe): a pose goes to the robot as
    the joints IK gives on ``chain`` (from the last joints reached; ``home`` for restarts), so
    the controller's own model plays no part; a touch is followed by a joint capture of
    ``capture_duration`` [s] read by FK on ``chain``; landmark frames are measured with
    ``landmarks`` (core.landmarks.views.measure_frame). Port errors become TrialErrors."""

    def __init__(self, port: RobotPort, chain: kinematics.Chain, home: Array,
                 capture_duration: float, landmarks: LandmarkRig | None = None,
                 cancelled: Cancelled = never) -> None:
        self.port, self.chain, self.landmarks = port, chain, landmarks
        self._home, self._q = np.asarray(home, dtype=float), np.asarray(home, dtype=float)
        self._capture_duration, self._cancelled = capture_duration, cancelled

    @property
    def robot_seconds(self) -> float:
        return self.port.robot_seconds

    def touch(self, name: str) -> Array:
        try:
            self.port.touch(name)
            self._q = self.port.capture(self._capture_duration).q
        except PortError as e:
            raise TrialError(ErrorCode.MOTION_FAILED, f'teaching {name}: {e}')
        return kinematics.fk(self.chain, self._q)

    def move(self, T_base_tool: Array) -> None:
        ik = kinematics.solve_ik_with_restarts(self.chain, T_base_tool, self._q, self._home)
        if not ik:
            raise TrialError(ErrorCode.MOTION_FAILED,
                             f'no inverse kinematics solution: {ik.message}')
        try:
            self._q = self.port.move_joints(ik.q)
        except PortError as e:
            raise TrialError(ErrorCode.MOTION_FAILED, str(e))

    def read(self) -> Reading:
        try:
            return self.port.probe()
        except PortError as e:
            raise TrialError(ErrorCode.PROBE_FAILED, str(e))

    def landmark_frame(self, method: str, T_base_user_guess: Array) -> Array:
        rig = self.landmarks
        if rig is None:
            raise TrialError(ErrorCode.INVALID_INPUT,
                             f'{method}: the cell has no wrist camera or no '
                             'landmarks; add camera: and landmarks: to the cell')
        try:
            result = views.measure_frame(
                method, rig.cell, self.port, rig.camera, T_base_user_guess=T_base_user_guess,
                plan_chain=rig.plan_chain, chain=rig.chain,
                capture_duration=self._capture_duration, max_rms_error=MAX_RMS_ERROR,
                max_scale_error=MAX_SCALE_ERROR, cancelled=self._cancelled,
                on_view=rig.on_view)
        except Stopped as e:
            raise TrialError(ErrorCode.CANCELED, f'{e}; send the same trial_id again to resume it')
        if result.code in (ErrorCode.INVALID_INPUT, ErrorCode.CAPTURE_FAILED):
            raise TrialError(result.code, result.message)
        if not result:
            raise TrialError(ErrorCode.INVALID_INPUT, f'{method}: {result.message}')
        return result.fit.M


@dataclass(frozen=True)
class ProbeRange:
    """The probe's measuring range, from its calibration table (proximity_sensor's)."""

    g_min: float             # [m]
    g_max: float             # [m]
    margin: float = 0.0      # readings this close to a range end count as out of range [m]

    @property
    def middle(self) -> float:
        return 0.5 * (self.g_min + self.g_max)


@dataclass
class Plan:
    trial_id: str
    method: str
    axis: str
    layout: str
    markers: Sequence[Marker]          # nominal geometry (the user's knowledge)
    cycles: int
    probe: ProbeRange
    approach_distance: float = 0.005   # retreat before each arrival: unidirectional approach [m]
    robust_threshold: float = user_frame.ROBUST_THRESHOLD
    extra: dict = field(default_factory=dict)

    def check(self) -> None:
        problem = first_failure(method_problem(self.method), axis_problem(self.axis),
                                cycles_problem(self.cycles))
        if problem is not None:
            raise TrialError(problem.code, problem.message)
        if self.method != 'reference' and len(self.markers) < 3:
            raise TrialError(ErrorCode.INVALID_INPUT, f'{self.method} needs at least 3 points')


def method_problem(method: str) -> Failure | None:
    """None if ``method`` is one of METHODS, else an INVALID_INPUT Failure (one line)."""
    return None if method in METHODS else Failure(
        ErrorCode.INVALID_INPUT, f'unknown method {method!r}; use one of {", ".join(METHODS)}')


def axis_problem(axis: str) -> Failure | None:
    """None if ``axis`` is one of AXES, else an INVALID_INPUT Failure (one line)."""
    return None if axis in AXES else Failure(
        ErrorCode.INVALID_INPUT, f'unknown axis {axis!r}; use one of {", ".join(AXES)}')


def cycles_problem(cycles: int) -> Failure | None:
    """None if ``cycles`` is a valid number of cycles, else an INVALID_INPUT Failure."""
    if not MIN_CYCLES <= cycles <= MAX_CYCLES:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'cycles must be {MIN_CYCLES}..{MAX_CYCLES} (RP needs the spread of at '
                       f'least {MIN_CYCLES} cycles), got {cycles}')
    return None


def goal_problem(method: str, axis: str, cycles: int) -> Failure | None:
    """None if a trial request is valid, else an INVALID_INPUT Failure (one line); the client
    and the node both check it. '' and 0 stand for "not given" (the default, or the stored
    value on resume)."""
    return first_failure(method_problem(method) if method else None,
                         axis_problem(axis) if axis else None,
                         cycles_problem(cycles) if cycles else None)


def resume_problem(meta: dict, method: str, axis: str, cycles: int) -> Failure | None:
    """None if a request may resume the stored trial ``meta``, else an INVALID_INPUT Failure
    saying why not (one line).

    Given values must equal the stored ones; '' and 0 take the stored ones."""
    asked = {'method': method, 'axis': axis, 'cycles': cycles}
    stored = {'method': meta['method'], 'axis': meta['axis'], 'cycles': meta['cycles_total']}
    differ = [f'{key} {asked[key]} (stored: {stored[key]})' for key in asked
              if asked[key] and asked[key] != stored[key]]
    if not differ:
        return None
    return Failure(ErrorCode.INVALID_INPUT,
                   f'trial {meta["id"]} is {describe(meta)}; cannot resume it with '
                   f'{", ".join(differ)}: leave those out to resume it, or pick a new trial id')


def describe(meta: dict) -> str:
    """'rigid, z axis, 30 cycles' for a trial's metadata."""
    return f'{meta["method"]}, {meta["axis"]} axis, {meta["cycles_total"]} cycles'


def new_trial_id(method: str, axis: str) -> str:
    """A fresh trial id from the local time: 20261122T153000-rigid-z."""
    return time.strftime(f'%Y%m%dT%H%M%S-{method or DEFAULT_METHOD}-{axis or DEFAULT_AXIS}')


def face_offset_user(marker: Marker, axis: str) -> Array:
    """From the nominal top-face centre to the centre of the face the probe looks at [m]."""
    sx, sy, sz = marker.size
    return {'z': np.zeros(3), 'x': np.array([-sx / 2, 0.0, -sz / 2]),
            'y': np.array([0.0, -sy / 2, -sz / 2])}[axis]


def probe_pose(R_base_user: Array, face_base: Array, axis: str, standoff: float) -> Array:
    """Tool pose looking along the user ``axis`` at ``face_base``, ``standoff`` [m] before it."""
    T = np.eye(4)
    T[:3, :3] = tool_down_orientation(_as_transform(R_base_user), axis)
    T[:3, 3] = face_base - standoff * T[:3, 2]
    return T


def retreat(T: Array, distance: float) -> Array:
    """The same pose moved back along the probe axis by ``distance`` [m]."""
    out = T.copy()
    out[:3, 3] -= distance * T[:3, 2]
    return out


def taught_user_rotation(T_touch: Array) -> Array:
    """User-frame axes at a taught marker: the touch pose has the tool z down the user z."""
    return T_touch[:3, :3] @ frames.rot_x(math.pi).T


def statistics(trial: TrialData) -> PointStats:
    return point_statistics(trial.distances)


Progress = Callable[[int, int, float], None]      # cycle, point index, corrected distance [m]
CycleDone = Callable[[int, PointStats], None]     # cycles completed, statistics so far


class TrialRun:
    """Runs (or resumes) one trial; every reading is stored before the next move."""

    def __init__(self, plan: Plan, robot: Robot, store: TrialStore,
                 on_reading: Progress | None = None, on_cycle: CycleDone | None = None,
                 stop_requested: Callable[[], bool] = lambda: False) -> None:
        plan.check()
        self.plan, self.robot, self.store = plan, robot, store
        self._on_reading = on_reading or (lambda *_: None)
        self._on_cycle = on_cycle or (lambda *_: None)
        self._stop_requested = stop_requested
        self._taught: list[Array] = []
        self._standoff: dict[str, list[float]] = {}

    # -- set-up ---------------------------------------------------------------------------
    def start(self) -> TrialData:
        """Teach the points, find the offsets F_i, create the trial, run every cycle."""
        self._teach()
        self.store.create(self.plan.trial_id, method=self.plan.method, axis=self.plan.axis,
                          layout=self.plan.layout, point_names=self._names(),
                          cycles_total=self.plan.cycles,
                          extra={**self.plan.extra, 'taught': self._taught,
                                 'standoff_m': self._standoff,
                                 'probe_range_m': [self.plan.probe.g_min,
                                                   self.plan.probe.g_max]})
        return self._run(self.store.load(self.plan.trial_id))

    def resume(self, trial: TrialData) -> TrialData:
        """Carry on a stored trial from the start of its interrupted cycle (same taught poses).

        The interrupted cycle is measured again from its first point, not carried on from its
        first unmeasured one: a cycle's readings must all go through that cycle's frame M_n,
        and M_n comes from the calibration pass at the start of the cycle. Refitting M_n for
        the rest of the cycle would mix two frames in one cycle; storing M_n with the
        readings would keep the frame but not the robot it was fitted on (a restart may come
        after a re-home, a power cycle or a cool-down), and ISO 9283 wants each cycle to visit
        P1..Pm in order anyway, also for the reference. Redoing the cycle costs at most m - 1
        readings; the store lets the new line for a (cycle, point) supersede the old one, and
        a cycle only counts once its last point is stored, after its first ones again.
        """
        self._taught = [np.array(T) for T in trial.meta['taught']]
        self._standoff = {a: list(v) for a, v in trial.meta['standoff_m'].items()}
        self.store.set_status(self.plan.trial_id, 'running')    # also marks it the latest
        return self._run(trial)

    def _names(self) -> list[str]:
        return [m.name for m in self.plan.markers]

    def _teach(self) -> None:
        self._taught = [self.robot.touch(m.name) for m in self.plan.markers]
        axes = {'z', self.plan.axis} if self.plan.method != 'reference' else {self.plan.axis}
        for axis in sorted(axes):
            self._standoff[axis] = [
                self._find_standoff(lambda s, i=i, a=axis: self._taught_pose(i, a, s))
                for i in range(len(self.plan.markers))]

    def _find_standoff(self, pose_at: Callable[[float], Array]) -> float:
        """F_i: the standoff [m] at which the probe reads the middle of its range."""
        probe = self.plan.probe
        standoff = probe.middle
        for _ in range(6):
            reading = self._visit(pose_at(standoff))
            if reading.status == ReadingStatus.OK:
                return standoff + probe_offset(reading.distance, probe.g_min, probe.g_max)
            step = 0.5 * (probe.g_max - probe.g_min)
            standoff += step if reading.status == ReadingStatus.BELOW_RANGE else -step
        raise TrialError(ErrorCode.PROBE_FAILED,
                         'the probe never read in range near a marker; check the '
                         'probe range parameters and that the markers are where the cell says')

    # -- poses ----------------------------------------------------------------------------
    def _taught_pose(self, i: int, axis: str, standoff: float) -> Array:
        T_touch = self._taught[i]
        R = taught_user_rotation(T_touch)
        face = T_touch[:3, 3] + R @ face_offset_user(self.plan.markers[i], axis)
        return probe_pose(R, face, axis, standoff)

    def _frame_pose(self, M: Array, i: int, axis: str, standoff: float) -> Array:
        marker = self.plan.markers[i]
        face = frames.apply(M, marker.nominal_top + face_offset_user(marker, axis))
        return probe_pose(user_frame.nearest_rigid(M)[:3, :3], face, axis, standoff)

    # -- cycles ---------------------------------------------------------------------------
    def _run(self, trial: TrialData) -> TrialData:
        try:
            return self._cycles(trial)
        except TrialError:
            self.store.set_status(self.plan.trial_id, 'aborted')   # not running any more
            raise

    def _cycles(self, trial: TrialData) -> TrialData:
        while trial.resume is not None:
            cycle = trial.resume[0]     # a whole cycle, from its first point (see resume)
            M = None if self.plan.method == 'reference' else self._cycle_frame(cycle)
            for i in range(len(self.plan.markers)):
                self._check_stop()
                self._measure(cycle, i, M)
            trial = self.store.load(self.plan.trial_id)
            stats = statistics(trial)
            self._on_cycle(cycle + 1, stats)
        self.store.set_status(self.plan.trial_id, 'done')
        return self.store.load(self.plan.trial_id)

    def _check_stop(self) -> None:
        if self._stop_requested():
            raise TrialError(ErrorCode.CANCELED, f'trial {self.plan.trial_id} stopped on request; '
                             'send the same trial_id again to resume it')

    def _cycle_frame(self, cycle: int) -> Array:
        """This cycle's M_n; the robot time of its calibration pass goes to the store."""
        started = self.robot.robot_seconds
        if self.plan.method in LANDMARK_METHODS:
            M = self.robot.landmark_frame(self.plan.method, self._taught_frame())
        else:
            M = self._probed_frame(cycle)
        self.store.record_calibration_time(self.plan.trial_id, cycle,
                                           self.robot.robot_seconds - started)
        return M

    def _taught_frame(self) -> Array:
        """T_base_user of the taught points (rigid): where landmark views are planned."""
        nominal = np.array([m.nominal_top for m in self.plan.markers])
        fit = user_frame.calibrate('rigid', nominal, np.array([T[:3, 3] for T in self._taught]))
        if not fit:
            raise TrialError(ErrorCode.INVALID_INPUT,
                             f'the taught points give no frame: {fit.message}')
        return fit.T_base_user

    def _probed_frame(self, cycle: int) -> Array:
        """M_n from the top faces probed at the taught positions."""
        measured = []
        for i in range(len(self.plan.markers)):
            self._check_stop()
            T = self._taught_pose(i, 'z', self._standoff['z'][i])
            reading = self._visit(T)
            if reading.status != ReadingStatus.OK:
                raise TrialError(ErrorCode.PROBE_FAILED,
                                 f'cycle {cycle + 1}: calibration reading at '
                                 f'{self.plan.markers[i].name} out of range '
                                 f'({reading.status.name})')
            measured.append(T[:3, 3] + reading.distance * T[:3, 2])
        nominal = np.array([m.nominal_top for m in self.plan.markers])
        opts = {'threshold': self.plan.robust_threshold} if self.plan.method == 'robust' else {}
        fit = user_frame.calibrate(self.plan.method, nominal, np.array(measured), **opts)
        if not fit:
            raise TrialError(ErrorCode.INVALID_INPUT,
                             f'cycle {cycle + 1}: {self.plan.method} fit failed: '
                             f'{fit.message}')
        return fit.M

    def _measure(self, cycle: int, i: int, M: Array | None) -> None:
        axis, standoff = self.plan.axis, self._standoff[self.plan.axis][i]
        T = (self._taught_pose(i, axis, standoff) if M is None
             else self._frame_pose(M, i, axis, standoff))
        reading, ff, direction = self._visit(T), 0.0, None
        for _ in range(MAX_FF_STEPS):   # eq (15): move by FF_i,n, correct the reading
            if reading.status == ReadingStatus.OK:
                break
            step, way = self._range_correction(reading)
            if direction not in (None, way):
                break                   # the gap is between two steps: no reading there
            ff, direction = ff + step, way
            reading = self._visit(retreat(T, ff if direction == 'away' else -ff))
        if reading.status != ReadingStatus.OK:
            raise TrialError(ErrorCode.PROBE_FAILED,
                             f'cycle {cycle + 1}, {self.plan.markers[i].name}: '
                             f'probe still {reading.status.name} after FF = '
                             f'{ff * 1e3:.2f} mm; check the frame and the offsets')
        corrected = self.store.append(self.plan.trial_id, cycle, i, reading.distance,
                                      ff, direction)
        self._on_reading(cycle, i, corrected)

    def _range_correction(self, reading: Reading) -> tuple[float, str]:
        """FF_i,n of eq (15) for an out-of-range reading: the reading only bounds the gap by
        the range end it passed, so that end is the predicted gap."""
        probe = self.plan.probe
        bound = probe.g_min if reading.status == ReadingStatus.BELOW_RANGE else probe.g_max
        ff, direction = range_correction(bound, probe.g_min, probe.g_max,
                                         max(probe.margin, 1e-9))
        return ff, direction

    def _visit(self, T: Array) -> Reading:
        """Unidirectional approach: arrive along the probe axis from a retreat pose."""
        self.robot.move(retreat(T, self.plan.approach_distance))
        self.robot.move(T)
        return self.robot.read()


def mean_calibration_seconds(meta: dict) -> float:
    """Mean robot time [s] of the calibration passes a stored trial measured; NaN if none."""
    times = [t for t in meta.get('calibration_s') or [] if t is not None]
    return float(np.mean(times)) if times else math.nan


def _as_transform(R: Array) -> Array:
    T = np.eye(4)
    T[:3, :3] = R
    return T
