"""The one simulated robot: plans with the nominal model, lands where the true model puts it.

Used by the mock_robot node and by in-process tests. The controller plans with the nominal
kinematic model, as a real controller does; the tool ends up where the true model puts it,
plus unidirectional repeatability noise that the encoders do not see. Joint readings carry
encoder noise. Motion and sensors draw from separate random streams (both from the scenario's
seed): the 1 kHz sensor thread and the motion thread never share a generator, and a seed
reproduces a run.
"""
from __future__ import annotations

import threading

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.driver import move_seconds
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.robot_port import Approach, Capture, CaptureFailed, MoveFailed
from cobot_calib_ros.core.sensors.probe import (average, ProbeCurve, Reading, read_distance,
                                                ReadingStatus)
from cobot_calib_ros.sim.scenario import Simulation

Array = NDArray[np.float64]
MOTION_STREAM, SENSOR_STREAM, IMAGE_STREAM = 0, 1, 2


class SimRobot:
    """Joint state, true tool pose and sensors of the simulated arm; thread-safe."""

    def __init__(self, sim: Simulation, seed_offset: int = 1000) -> None:
        self.sim, self.cell = sim, sim.cell
        self.model = kinematics.model_for(self.cell)
        self.true_parameters = sim.true_parameters(self.model)
        self.nominal = self.model.chain(tool=self.cell.T_flange_tool)
        self.true = self.model.chain(self.true_parameters, tool=sim.T_flange_tool_true)
        spheres = sim.spheres
        self.coupling = None if spheres is None else self.model.chain(
            self.true_parameters, tool=spheres.T_flange_coupling) # true chain to the coupling
        streams = np.random.SeedSequence(sim.seed + seed_offset).spawn(3)
        self._motion_rng = np.random.default_rng(streams[MOTION_STREAM])
        self._sensor_rng = np.random.default_rng(streams[SENSOR_STREAM])
        # the wrist camera's sensor noise (sim.camera.SimCamera): its own stream, so an image's
        # noise depends on the seed and the images drawn before it, not on the process
        self.image_rng = np.random.default_rng(streams[IMAGE_STREAM])
        self._lock = threading.Lock()
        self._q = self.cell.home.copy()
        self._tool_noise = np.zeros(3)
        self._T_true = kinematics.fk(self.true, self._q)
        self._gap: float | None = None      # the probe's true gap [m] at _T_true, once asked

    # -- state ----------------------------------------------------------------------------
    @property
    def q(self) -> Array:
        with self._lock:
            return self._q.copy()

    def true_tool(self) -> Array:
        with self._lock:
            return self._T_true.copy()

    def set_joints(self, q: Array) -> None:
        """Put the arm at ``q`` [rad] on its way somewhere: no repeatability noise yet."""
        self._set(q, np.zeros(3))

    def settle(self, q: Array) -> None:
        """Come to rest at ``q``: the tool lands within the unidirectional repeatability."""
        T = kinematics.fk(self.true, q)
        sigma = self.sim.repeatability_sigma_at(T[:3, 3])
        self._set(q, self._motion_rng.normal(0.0, sigma, 3))

    def _set(self, q: Array, tool_noise: Array) -> None:
        T = kinematics.fk(self.true, q)
        T[:3, 3] += tool_noise
        with self._lock:
            self._q = np.asarray(q, dtype=float).copy()
            self._tool_noise = tool_noise
            self._T_true, self._gap = T, None

    # -- planning (motion thread) ---------------------------------------------------------
    def plan_joints(self, q: Array) -> Array | Failure:
        """``q`` itself if it is a valid joint target [rad], else why not."""
        q = np.asarray(q, dtype=float)
        if q.shape != self._q.shape or not np.all(np.isfinite(q)):
            return Failure(ErrorCode.INVALID_INPUT, f'expected {len(self._q)} finite joint '
                           f'positions [rad], got {q.tolist()}')
        bad = np.flatnonzero((q < self.nominal.lower) | (q > self.nominal.upper))
        if bad.size:
            names = [self.model.joint_names[i] for i in bad]
            return Failure(ErrorCode.INVALID_INPUT, f'joint target outside the limits of {names}')
        return q

    def plan_pose(self, T_base_tool: Array) -> Array | Failure:
        """Joints that put the tool at ``T_base_tool`` by the nominal model (the controller)."""
        return self._solve(self.nominal, T_base_tool)

    def plan_touch(self, name: str, axis: str = 'z',
                   approach: Approach | None = None) -> Array | Failure:
        """The operator hand-guides the real tool tip onto marker ``name`` (with centring
        error): joints that put the TRUE tool there, pointing along the user ``axis``, or as
        ``approach`` asks (its orientation; an elongator point along the true tool's axis,
        as an operator lines one up on the real tool)."""
        marker = self.sim.world.marker(name)
        if marker is None:
            return Failure(ErrorCode.INVALID_INPUT, f'unknown point {name!r}; the cell has '
                           f'{self.sim.world.point_names}')
        T_base_user = self.sim.world.T_base_user
        R = tool_down_orientation(T_base_user, axis) if approach is None \
            else np.asarray(approach.orientation, dtype=float)
        point = frames.apply(T_base_user, marker.true_top)
        if approach is not None and approach.axis:
            point = point + approach.distance * R[:, 'xyz'.index(approach.axis)]
        target = frames.make_transform(
            R, point + self._motion_rng.normal(0.0, self.sim.noise.touch_sigma, 3))
        return self._solve(self.true, target)

    def plan_compliant(self, q: Array) -> Array | Failure:
        """Where the arm comes to rest when sent to ``q`` under impedance control [rad].

        If the true coupling centre ends up within the capture radius of a sphere, the
        coupling self-centres on it: the arm yields in translation (orientation held) until
        the true coupling centre is on the sphere centre, within the compliance error.
        Otherwise ``q`` itself.
        """
        q = self.plan_joints(q)
        if isinstance(q, Failure) or self.coupling is None:
            return q
        spheres = self.sim.spheres
        T = kinematics.fk(self.coupling, q)
        i, distance = spheres.nearest(T[:3, 3])
        if distance > spheres.capture_radius:
            return q
        T[:3, 3] = spheres.centres_base[i] + self._motion_rng.normal(
            0.0, spheres.compliance_sigma, 3)
        result = kinematics.solve_ik(self.coupling, T, q, tol=1e-12)
        if not result:
            return Failure(ErrorCode.MOTION_FAILED, f'coupling on sphere {i}: {result.message}')
        return result.q

    def laser_measurement(self) -> Array:
        """(3,) the true coupling centre as the laser tracker measures it, tracker frame [m]."""
        if self.coupling is None:
            raise ValueError('this cell has no sphere plate, coupling or laser tracker')
        p = kinematics.fk(self.coupling, self.q)[:3, 3]
        return self.sim.spheres.tracker.measure(p, self._sensor_rng)

    def _solve(self, chain: kinematics.Chain, T: Array) -> Array | Failure:
        if not np.all(np.isfinite(T)):
            return Failure(ErrorCode.INVALID_INPUT, 'target pose has NaN or inf')
        result = kinematics.solve_ik_with_restarts(chain, T, self.q, self.cell.home)
        if not result:
            return Failure(ErrorCode.MOTION_FAILED,
                           f'no inverse kinematics solution: {result.message}')
        return result.q

    # -- sensors (sensor thread) ----------------------------------------------------------
    def joint_reading(self) -> Array:
        """Encoder positions [rad]: commanded joints plus encoder noise."""
        return self.joint_readings(1)[0]

    def joint_readings(self, count: int) -> Array:
        """``count`` encoder readings [rad] (rows) of the joints where they are now."""
        q = self.q
        return q + self._sensor_rng.normal(0.0, self.sim.noise.encoder_sigma, (count, q.size))

    def probe_voltage(self) -> float:
        """Probe output [V] for the true gap under the true tool pose, with sensor noise."""
        with self._lock:
            T_true, gap = self._T_true, self._gap
        if gap is None:         # the arm moved: a ray cast (200 Hz at rest is the same gap)
            gap = self.sim.world.probe_gap(T_true)
            with self._lock:
                if self._T_true is T_true:
                    self._gap = gap
        return self.sim.probe.to_voltage(gap) + self._sensor_rng.normal(
            0.0, self.sim.noise.probe_voltage_sigma)


class DirectRobot:
    """core.robot_port.RobotPort on a SimRobot, in-process (no ROS): for tests.

    Moves settle at once (robot time: core.driver.move_seconds at ``joint_velocity``, as
    mock_robot reports it), a touch is the simulated operator's hand-guiding (as mock_robot's
    hand_guide), a capture averages encoder readings at the cell's joint_states rate, and the
    probe reads ``samples`` voltages through ``probe_table``, the user's calibration table, and
    averages them as proximity_sensor does (core.sensors.probe.average).
    """

    def __init__(self, sim: SimRobot, probe_table: ProbeCurve, samples: int = 4,
                 saturation_margin: float = 2e-6, joint_velocity: float = 1.0) -> None:
        self.sim, self.table = sim, probe_table
        self.samples, self.margin = samples, saturation_margin
        self.joint_velocity = joint_velocity    # [rad/s] as mock_robot's default
        self.moves = 0
        self.robot_seconds = 0.0

    def _go(self, q: Array | Failure) -> Array:
        if isinstance(q, Failure):
            raise MoveFailed(q.message)
        self.robot_seconds += float(move_seconds(self.sim.q, q, self.joint_velocity))
        self.sim.settle(q)
        self.moves += 1
        return self.sim.q

    def move_joints(self, q: Array, *, compliant: bool = False) -> Array:
        reached = self._go(self.sim.plan_joints(q))
        if compliant:       # as mock_robot: settle at the target, then yield to the sphere
            rest = self.sim.plan_compliant(reached)
            if isinstance(rest, Failure):
                raise MoveFailed(rest.message)
            self.sim.set_joints(rest)
        return self.sim.q

    def move_to_pose(self, T_base_tool: Array) -> Array:
        return self._go(self.sim.plan_pose(T_base_tool))

    def touch(self, name: str, approach: Approach | None = None) -> None:
        self._go(self.sim.plan_touch(name, approach=approach))

    def capture(self, duration: float) -> Capture:
        count = max(1, round(duration * self.sim.sim.joint_states_hz))
        readings = np.array([self.sim.joint_reading() for _ in range(count)])
        self.robot_seconds += duration
        return Capture(readings.mean(axis=0), readings.std(axis=0, ddof=1) if count > 1
                       else np.zeros(readings.shape[1]), count)

    def probe(self) -> Reading:
        period_ns = round(1e9 / self.sim.sim.probe_hz)
        window = [(k * period_ns, *_fields(read_distance(self.table, self.sim.probe_voltage(),
                                                         self.margin)))
                  for k in range(self.samples)]
        duration = self.samples / self.sim.sim.probe_hz
        self.robot_seconds += duration
        result = average(window, duration)
        reading = result.reading()
        if reading is None:
            raise CaptureFailed(f'probe: {result.message}')
        return reading

    def measure_position(self) -> Array:
        try:
            return self.sim.laser_measurement()
        except ValueError as e:
            raise CaptureFailed(str(e))


def _fields(reading: Reading) -> tuple[float, ReadingStatus]:
    return reading.distance, reading.status
