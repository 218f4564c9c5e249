"""The one simulated robot: plans with the nominal model, lands where the true model puts it.

Used by the mock_robot node and by in-process tests. The controller plans with the nominal
kinematic model, as a real controller does; the tool ends up where the true model puts it,
plus unidirectional repeatability noise that the encoders do not see. Joint readings carry
encoder noise. Motion and sensors draw from separate random streams (both from the scenario's
seed): the 1 kHz sensor thread and the motion thread never share a generator, and a seed
reproduces a run.
"""
from __future__ import annotations

import math
import threading

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.errors import Failure, MotionCode
from cobot_calib_ros.core.repeatability.trial import Reading, TrialError
from cobot_calib_ros.core.sensors.probe import ProbeCurve, read_distance, ReadingStatus
from cobot_calib_ros.sim.scenario import Simulation

Array = NDArray[np.float64]
MOTION_STREAM, SENSOR_STREAM = 0, 1


class SimRobot:
    """Joint state, true tool pose and sensors of the simulated arm; thread-safe."""

    def __init__(self, sim: Simulation, seed_offset: int = 1000) -> None:
        self.sim, self.cell = sim, sim.cell
        self.model = kinematics.model_by_name(self.cell.robot)
        self.true_parameters = sim.true_parameters(self.model)
        self.nominal = self.model.chain(tool=self.cell.tool_offset)
        self.true = self.model.chain(self.true_parameters, tool=self.cell.tool_offset)
        spheres = sim.spheres
        self.coupling = None if spheres is None else self.model.chain(
            self.true_parameters, tool=spheres.coupling_offset)   # true chain to the coupling
        streams = np.random.SeedSequence(sim.seed + seed_offset).spawn(2)
        self._motion_rng = np.random.default_rng(streams[MOTION_STREAM])
        self._sensor_rng = np.random.default_rng(streams[SENSOR_STREAM])
        self._lock = threading.Lock()
        self._q = self.cell.home.copy()
        self._tool_noise = np.zeros(3)
        self._T_true = kinematics.fk(self.true, self._q)

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
            self._T_true = T

    # -- planning (motion thread) ---------------------------------------------------------
    def plan_joints(self, q: Array) -> Array | Failure:
        """``q`` itself if it is a valid joint target [rad], else why not."""
        q = np.asarray(q, dtype=float)
        if q.shape != self._q.shape or not np.all(np.isfinite(q)):
            return Failure(MotionCode.INVALID_TARGET, f'expected {len(self._q)} finite joint '
                           f'positions [rad], got {q.tolist()}')
        bad = np.flatnonzero((q < self.nominal.lower) | (q > self.nominal.upper))
        if bad.size:
            names = [self.model.joint_names[i] for i in bad]
            return Failure(MotionCode.INVALID_TARGET, f'joint target outside the limits of {names}')
        return q

    def plan_pose(self, T_base_tool: Array) -> Array | Failure:
        """Joints that put the tool at ``T_base_tool`` by the nominal model (the controller)."""
        return self._solve(self.nominal, T_base_tool)

    def plan_touch(self, name: str, axis: str = 'z') -> Array | Failure:
        """The operator hand-guides the real tool tip onto marker ``name`` (with centring
        error): joints that put the TRUE tool there."""
        marker = self.sim.world.marker(name)
        if marker is None:
            return Failure(MotionCode.INVALID_TARGET, f'unknown point {name!r}; the cell has '
                           f'{self.sim.world.point_names}')
        T_base_user = self.sim.world.T_base_user
        target = frames.make_transform(
            tool_down_orientation(T_base_user, axis),
            frames.apply(T_base_user, marker.true_top)
            + self._motion_rng.normal(0.0, self.sim.noise.touch_sigma, 3))
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
            return Failure(MotionCode.UNREACHABLE, f'coupling on sphere {i}: {result.message}')
        return result.q

    def laser_measurement(self) -> Array:
        """(3,) the true coupling centre as the laser tracker measures it, tracker frame [m]."""
        if self.coupling is None:
            raise ValueError('this cell has no sphere plate, coupling or laser tracker')
        p = kinematics.fk(self.coupling, self.q)[:3, 3]
        return self.sim.spheres.tracker.measure(p, self._sensor_rng)

    def _solve(self, chain: kinematics.Chain, T: Array) -> Array | Failure:
        if not np.all(np.isfinite(T)):
            return Failure(MotionCode.INVALID_TARGET, 'target pose has NaN or inf')
        result = kinematics.solve_ik_with_restarts(chain, T, self.q, self.cell.home)
        if not result:
            return Failure(MotionCode.UNREACHABLE,
                           f'no inverse kinematics solution: {result.message}')
        return result.q

    # -- sensors (sensor thread) ----------------------------------------------------------
    def joint_reading(self) -> Array:
        """Encoder positions [rad]: commanded joints plus encoder noise."""
        q = self.q
        return q + self._sensor_rng.normal(0.0, self.sim.noise.encoder_sigma, q.shape)

    def probe_voltage(self) -> float:
        """Probe output [V] for the true gap under the true tool pose, with sensor noise."""
        gap = self.sim.world.probe_gap(self.true_tool())
        return self.sim.probe.to_voltage(gap) + self._sensor_rng.normal(
            0.0, self.sim.noise.probe_voltage_sigma)


class DirectRobot:
    """core.repeatability.trial.Robot on a SimRobot, in-process (no ROS): for tests.

    Reads the probe through ``probe_table``, the user's calibration table (as
    proximity_sensor does), averaging ``samples`` voltages per reading.
    """

    def __init__(self, sim: SimRobot, probe_table: ProbeCurve, samples: int = 4,
                 saturation_margin: float = 2e-6, joint_velocity: float = 1.0,
                 hand_eye: Array | None = None) -> None:
        self.sim, self.table = sim, probe_table
        self.samples, self.margin = samples, saturation_margin
        self.joint_velocity = joint_velocity    # [rad/s] as mock_robot's default
        self.moves = 0
        self.robot_seconds = 0.0
        self._camera = None
        self.hand_eye = hand_eye    # T_flange_optical landmark frames use; None: the nominal

    def _go(self, q: Array | Failure) -> None:
        if isinstance(q, Failure):
            raise TrialError('motion', q.message)
        self.robot_seconds += float(np.max(np.abs(q - self.sim.q))) / self.joint_velocity
        self.sim.settle(q)
        self.moves += 1

    def touch(self, name: str) -> Array:
        self._go(self.sim.plan_touch(name))
        return kinematics.fk(self.sim.nominal, self.sim.q)

    def move(self, T_base_tool: Array) -> None:
        self._go(self.sim.plan_pose(T_base_tool))

    def read(self) -> Reading:
        readings = [read_distance(self.table, self.sim.probe_voltage(), self.margin)
                    for _ in range(self.samples)]
        self.robot_seconds += self.samples / self.sim.sim.probe_hz
        ok = [r.distance for r in readings if r.status == ReadingStatus.OK]
        if len(ok) > len(readings) / 2:
            return Reading(float(np.mean(ok)), ReadingStatus.OK)
        statuses = [r.status for r in readings if r.status != ReadingStatus.OK]
        return Reading(math.nan, max(set(statuses), key=statuses.count))

    def landmark_frame(self, method: str, T_base_user_guess: Array) -> Array:
        """The landmark method's M_n as the ROS path measures it (core.landmarks.views): the
        views planned with the nominal hand-eye, images rendered by sim.camera at the arm's
        joints, markers detected and posed by core.landmarks, camera poses by the nominal
        model and ``hand_eye`` at the encoder readings."""
        from cobot_calib_ros.core.landmarks import views
        from cobot_calib_ros.core.landmarks.detect import detect_markers
        from cobot_calib_ros.core.landmarks.pose import estimate_marker_pose
        from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR
        from cobot_calib_ros.sim.camera import SimCamera
        cell = self.sim.cell
        if self._camera is None:
            self._camera = SimCamera(self.sim.sim, self.sim)
        camera, marks = self._camera.camera, cell.landmarks
        X = cell.camera.T_flange_optical if self.hand_eye is None else self.hand_eye
        chain = self.sim.model.chain(tool=X)
        observations = []
        for _, q in views.plan_views(method, cell, chain, T_base_user_guess, self.sim.q):
            self._go(self.sim.plan_joints(q))
            image = self._camera.render(self.sim.q)
            T_base_optical = kinematics.fk(chain, self.sim.joint_reading())
            for marker in detect_markers(image, marks.dictionary, camera=camera):
                pose = estimate_marker_pose(marker.corners, marks.marker_length, camera)
                if pose:
                    observations.append(views.observation(marker.id, T_base_optical,
                                                          pose.T_optical_target,
                                                          pose.covariance))
        result = views.landmark_frame(method, cell, observations, max_rms_error=MAX_RMS_ERROR,
                                      max_scale_error=MAX_SCALE_ERROR)
        if not result:
            why = result.fit.message if hasattr(result, 'fit') else result.message
            raise TrialError('invalid', f'{method}: {why}')
        return result.fit.M
