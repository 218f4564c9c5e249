"""Placement, measured end to end (issue 36 item 5): the first day of a new cell on the mock, then
the tool sent to targets in the user frame, scored against the frame the TRUE reference points
define.

In-process over the sim (sim.robot.DirectRobot, no ROS), for the mock Sawyer, iiwa 7 and UR10e
cells, with the same core calls the nodes make:
1. identify planned: core.kinematics.planned_collection.collect_planned over the SpherePlanner
   of planning.sphere_candidates (kinematic_identifier's default candidates, PlanSettings' 50
   poses), the collection identified by CalibrationJob, stored and activated (KinematicRecord);
2. TCP: core.tcp.touches plan_touches / checked_plan / take_touches / solve_touches and the
   gate (tcp_calibrator's defaults: 6 approaches of P1, 30 deg, no orientation method), the
   flange poses through the ACTIVE kinematics (store.rigs.rig_of, as the node's ``_chain``),
   stored and activated (TcpRecord);
3. user frame: P1..P5 touched (mock_robot's hand-guiding: the TRUE tool on the TRUE marker
   tops with the touch noise), the joints captured over 0.5 s, the points through the rig's
   ``tcp`` chain (active kinematics and TCP, as user_frame_solver), the rigid fit, stored and
   activated (UserFrameRecord);
4. hand-eye (cells with a camera): hand_eye_views / take_hand_eye_views over the sim's robot
   and camera, solve_hand_eye through the rig's flange chain (not stored). The hand-eye
   does not enter the tool's chain: it is here for the first day's completeness and its error
   against the truth (``placement_<robot>_hand_eye_error_mm``).

Then TARGETS tool poses in the user frame (seeded: over the markers' area and 20 mm around it,
0-50 mm above the table, the tool pointing down tilted up to 30 deg, turned up to 90 deg about
its axis; drawn again where the nominal arm cannot reach one 1 deg inside its joint limits)
are solved from home
- through ``move``: api.move.solve(frame='user', kinematics='active'), the code
  `cobot-calib move --frame user` runs;
- through robot_adapter in driver mode: store.rigs.rig_of(...).chain('tcp') and
  core.rig.solve_target of the target put in the base by the active user frame, the two calls
  robot_adapter's pose goal makes (its ``_pose_chain`` and ``_plan``);
and the arm is sent there (DirectRobot.move_joints: it lands within its repeatability). Error:
the TRUE tool tip (the mock's truth: true kinematics, true tool, the landing noise) against the
target put in the base by the frame the TRUE marker tops define (the rigid fit of the nominal
points to them: the design frame differs by the markers' height errors, which no calibration
sees). Figures [mm]:
- ``placement_<robot>_{nominal,calibrated}_{max,rms}_mm``: through ``move``; nominal: every
  result nominal (a repository with only a user frame touched through the nominal kinematics
  and tool), calibrated: the first day's results;
- ``placement_<robot>_calibrated_adapter_{max,rms}_mm``: through robot_adapter's calls;
- ``placement_<robot>_true_<result>_{max,rms}_mm``: one result swapped for the mock's truth and
  the results measured through it measured again from the same joints (kinematics: the TCP and
  the user frame through the true arm; tcp: the user frame through the true tool;
  user_frame: perfect touches, no touch noise), through robot_adapter's calls, to show which
  result's error dominates; ``..._true_nominal_{kinematics,tcp}_...``: the same from the
  nominal results (what the nominal figure owes to the arm and to the tool);
  ``..._all_true_...``: every result true;
- ``..._landed_...``: the same where the arm lands (its repeatability on top; all_true_landed
  is the repeatability alone);
- ``placement_<robot>_{kinematics,tcp}_error_mm`` and ``..._user_frame_error_{mm,mrad}``: each
  calibrated result against its truth (kinematics: the max tip error over the targets' joints
  after the best rigid registration: the base a sphere calibration cannot see, which the user
  frame absorbs; the user frame: at the markers' centre, against the true points' frame).
"""
from __future__ import annotations

import benchlib  # first: cobot_calib_ros before numpy (one BLAS thread), run alone too
import sys
import tempfile
import time

import numpy as np

from benchlib import Figures
from cobot_calib_ros import store
from cobot_calib_ros.api import move
from cobot_calib_ros.core import frames, kinematics, rig, user_frame
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.frames import Rotation
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.identification import register_rigid, SphereObservations
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
from cobot_calib_ros.core.kinematics.planned_collection import collect_planned
from cobot_calib_ros.core.kinematics.planning import (PlanSettings, sphere_candidates,
                                                      SpherePlanner)
from cobot_calib_ros.core.tcp import GateLimits, gate_problem
from cobot_calib_ros.core.tcp.touches import (checked_plan, plan_touches, solve_touches,
                                              take_touches)
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation, Simulation
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import KinematicRecord, TcpRecord, UserFrameRecord
from cobot_calib_ros.store.rigs import rig_of
from cobot_calib_ros.paths import DEFAULT_CELL

CELLS = {'sawyer': DEFAULT_CELL, 'iiwa7': 'iiwa7_close', 'ur10e': 'ur10e_close'}
TARGETS = 50
TARGET_SEED = 36
IDENTIFY_HOLD = 0.05        # [s] `identify`'s --hold default
TCP_HOLD = 0.2              # [s] tcp_calibrator's hold_duration
TOUCH_HOLD = 0.5            # [s] capture_joints' default
PLANNING_TASK_SEED = 1      # kinematic_identifier's task volume draw
TOUCH_SIGMA = 5e-5          # [m] tcp_calibrator's touch_sigma
MARGIN = 0.02               # [m] around the markers' area
MAX_TILT = np.radians(30.0)     # as the TCP calibration's approaches
MAX_TURN = np.radians(90.0)


class FirstDay:
    """One cell's first day on the mock and the two repositories it leaves."""

    def __init__(self, sim: Simulation, root: str) -> None:
        self.sim, self.cell = sim, sim.cell
        self.arm = SimRobot(sim)
        self.model = self.arm.model
        self.port = DirectRobot(self.arm, sim.probe)
        self.calibrated = store.open(f'{root}/calibrated', cell=ResultsCell.of(self.cell))
        self.nominal = store.open(f'{root}/nominal', cell=ResultsCell.of(self.cell))
        self.seconds: dict[str, float] = {}

    def _timed(self, step: str, run) -> None:
        start = time.perf_counter()
        run()
        self.seconds[step] = time.perf_counter() - start
        print(f'  {self.cell.name}: {step} {self.seconds[step]:.1f} s', file=sys.stderr)

    def run(self) -> None:
        self._timed('identify', self.identify)
        self._timed('tcp', self.tcp)
        self._timed('user_frame', self.user_frame)
        if self.cell.camera is not None and self.cell.landmarks is not None:
            self._timed('hand_eye', self.hand_eye)

    def identify(self) -> None:
        spheres = self.cell.spheres
        pool, _ = sphere_candidates(self.cell, self.model)
        task = plans.tracker_plan(self.cell, self.model, 'volume', plans.TRACKER_CONFIGS,
                                  PLANNING_TASK_SEED)
        planner = SpherePlanner(self.model, pool, spheres.known_distances(),
                                spheres.T_flange_coupling[:3, 3], [s['q'] for s in task],
                                PlanSettings())
        planner.start()
        collect_planned(planner, self.port, lambda record: None, hold=IDENTIFY_HOLD)
        data = SphereObservations(np.array(planner.q), np.array(planner.target),
                                  spheres.known_distances())
        outcome = CalibrationJob(self.cell, self.model, data).run()
        activation = self.calibrated.kinematics.save_and_activate(
            KinematicRecord.from_outcome(outcome, measured_through={}))
        if not activation:
            raise benchlib.BenchFailed(f'{self.cell.name}: identification not activated: '
                                       f'{activation.reason}')

    def tcp(self) -> None:
        active = rig_of(self.calibrated, self.cell, 'latest', self.model)
        point = self.cell.point_names[0]
        plan = plan_touches(point)
        plan, locate = checked_plan(plan, active.chain('tcp'), self.cell.home)
        touches = take_touches(plan, self.port, active.chain('flange'), TCP_HOLD,
                               locate=locate)
        self.tcp_plan, self.tcp_touches = plan, touches
        solution = solve_touches(plan, touches, TOUCH_SIGMA)
        gate = gate_problem(solution, GateLimits(touch_sigma=TOUCH_SIGMA), self.cell.T_flange_tool)
        gate = '' if gate is None else gate.message
        record = TcpRecord.from_solution(solution, self.cell.tool_frame, point, touches.labels,
                                         touches.joints, touches.flange, 0,
                                         active.active.kinematics_label, 0.52, 0.0, gate,
                                         {'kinematics': active.active.kinematics_label})
        activation = self.calibrated.tcp.save_and_activate(record)
        if not activation:
            raise benchlib.BenchFailed(f'{self.cell.name}: TCP not activated: {gate}')

    def user_frame(self) -> None:
        """P1..P5 touched once; fitted through the calibrated results and through the nominal
        ones (the same joints)."""
        names = self.cell.point_names
        joints = []
        for name in names:
            self.port.touch(name)
            joints.append(self.port.capture(TOUCH_HOLD).q)
        self.frame_joints = np.array(joints)
        p_user = self.cell.nominal_points_user()
        for repo, active in ((self.calibrated, rig_of(self.calibrated, self.cell, 'latest',
                                                      self.model)),
                             (self.nominal, rig.Rig(self.cell, model=self.model))):
            p_base = kinematics.fk(active.chain('tcp'), np.array(joints))[:, :3, 3]
            fit = user_frame.calibrate('rigid', p_user, p_base, names=names)
            record = UserFrameRecord.from_fit(
                fit, None, names, p_user, p_base, (self.cell.base_frame, self.cell.user_frame),
                0, active.active.kinematics_label, tcp=active.active.tcp_label,
                measured_through={'kinematics': active.active.kinematics_label,
                                  'tcp': active.active.tcp_label})
            activation = repo.user_frames.save_and_activate(record)
            if not activation:
                raise benchlib.BenchFailed(f'{self.cell.name}: user frame not activated: '
                                           f'{activation.reason}')

    def hand_eye(self) -> None:
        from cobot_calib_ros.core.landmarks.hand_eye import hand_eye_views, solve_hand_eye
        from cobot_calib_ros.core.landmarks.hand_eye_capture import take_hand_eye_views
        from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
        active = rig_of(self.calibrated, self.cell, 'latest', self.model)
        plan = hand_eye_views(self.cell, self.model, 12, 0, T_base_user=active.T_base_user())
        views = take_hand_eye_views(plan, self.port,
                                    DirectCamera(SimCamera(self.sim, self.arm), self.arm,
                                                 boards=True),
                                    active.chain('flange'), hold=TCP_HOLD,
                                    landmark_timeout=5.0)
        solved = solve_hand_eye(views.flange, views.boards, covariances=views.covariances)
        if not solved:
            raise benchlib.BenchFailed(f'{self.cell.name}: hand-eye: {solved.message}')
        self.T_flange_optical = solved.T_flange_optical


def targets(cell, model, T_base_user: np.ndarray, seed: int = TARGET_SEED) -> np.ndarray:
    """(TARGETS, 4, 4) tool poses in the user frame (module doc) that the nominal arm reaches
    through ``T_base_user`` with its joints 1 deg inside their limits (a program taught on the
    cell; the others are drawn again)."""
    from cobot_calib_ros.core.tcp.touches import JOINT_MARGIN
    rng = np.random.default_rng(seed)
    p = cell.nominal_points_user()
    lo, hi = p[:, :2].min(axis=0) - MARGIN, p[:, :2].max(axis=0) + MARGIN
    down = tool_down_orientation(np.eye(4), 'z')
    chain = rig.Rig(cell, model=model).chain('tcp')
    out = []
    while len(out) < TARGETS:
        xy = rng.uniform(lo, hi)
        z = p[:, 2].mean() + rng.uniform(0.0, 0.05)
        azimuth = rng.uniform(0.0, 2.0 * np.pi)
        tilt = rng.uniform(0.0, MAX_TILT) * np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        R = Rotation.from_rotvec(tilt).as_matrix() @ down @ frames.rot_z(
            rng.uniform(-MAX_TURN, MAX_TURN))
        T = frames.make_transform(R, [*xy, z])
        if kinematics.solve_ik_with_restarts(chain, T_base_user @ T, cell.home, cell.home,
                                             JOINT_MARGIN):
            out.append(T)
    return np.array(out)


def reference_frame(sim: Simulation) -> np.ndarray:
    """T_base_user that the TRUE marker tops define: the rigid fit of the nominal points to
    them (what a program's targets mean)."""
    return user_frame.calibrate('rigid', sim.cell.nominal_points_user(),
                                sim.world.true_points_base(), max_rms_error=None).T_base_user


def placed_mm(day: FirstDay, q: np.ndarray, target_base: np.ndarray) -> tuple[float, float]:
    """[mm] of the true tool tip from the target at ``q``: where the true arm and tool put it
    (the mean landing), and where it lands once the arm is sent there (with its
    repeatability)."""
    placed = kinematics.fk(day.arm.true, q)[:3, 3]
    day.port.move_joints(q)
    landed = day.arm.true_tool()[:3, 3]
    return (float(np.linalg.norm(placed - target_base[:3, 3]) * 1e3),
            float(np.linalg.norm(landed - target_base[:3, 3]) * 1e3))


def swapped_chain(day: FirstDay, swap: str):
    """(tcp chain, T_base_user): the first day's results with ``swap`` made the mock's truth
    and the results measured through it measured again from the same joints ('' none;
    'kinematics': the TCP and the user frame through the true arm; 'tcp': the user frame
    through the true tool; 'user_frame': perfect touches, the true tool put exactly on the
    true marker tops, through the calibrated chain; 'all': the truth)."""
    if swap == 'all':
        return day.arm.true, reference_frame(day.sim)
    if swap.startswith('nominal'):      # the nominal results, one made true
        params = day.arm.true_parameters if swap == 'nominal_kinematics' else None
        tool = day.sim.T_flange_tool_true if swap == 'nominal_tcp' else day.cell.T_flange_tool
        return _touched(day, day.model.chain(params, tool=tool), day.frame_joints)
    active = rig_of(day.calibrated, day.cell, 'latest', day.model)
    params = (day.arm.true_parameters if swap == 'kinematics'
              else active.active.kinematics.params)
    if swap == 'tcp':
        tool = day.sim.T_flange_tool_true
    elif swap == 'kinematics':
        tool = tcp_through(day, params)
    else:
        tool = active.tool('tcp')
    return _touched(day, day.model.chain(params, tool=tool),
                    day.frame_joints if swap != 'user_frame' else perfect_touches(day))


def _touched(day: FirstDay, chain, joints: np.ndarray):
    """(chain, T_base_user of the rigid fit of the touches ``joints`` through it)."""
    p_base = kinematics.fk(chain, joints)[:, :3, 3]
    return chain, user_frame.calibrate('rigid', day.cell.nominal_points_user(), p_base,
                                       max_rms_error=None).T_base_user


def tcp_through(day: FirstDay, params: np.ndarray) -> np.ndarray:
    """T_flange_tool solved from the TCP calibration's joints through the arm ``params``, as
    the rig uses it (the cell tool's orientation, the position measured)."""
    from cobot_calib_ros.core.tcp.touches import TcpTouches
    touches = day.tcp_touches
    flange = kinematics.fk(day.model.chain(params), np.array(touches.joints))
    again = TcpTouches(list(touches.labels), list(touches.joints), list(flange),
                       touches.approaches)
    T = np.array(day.cell.T_flange_tool, dtype=float)
    T[:3, 3] = solve_touches(day.tcp_plan, again, TOUCH_SIGMA).position.t
    return T


def perfect_touches(day: FirstDay) -> np.ndarray:
    """(N, n) joints that put the TRUE tool tip exactly on each TRUE marker top, pointing
    down the true user frame (mock_robot's hand-guiding without its touch noise)."""
    T_base_user = day.sim.world.T_base_user
    R = tool_down_orientation(T_base_user, 'z')
    out = []
    for q, p in zip(day.frame_joints, day.sim.world.true_points_base()):
        result = kinematics.solve_ik_with_restarts(day.arm.true, frames.make_transform(R, p),
                                                   q, day.cell.home)
        out.append(result.q)
    return np.array(out)


def errors(day: FirstDay, goals: np.ndarray) -> dict[str, np.ndarray]:
    """[mm] per target of every way of solving it (module doc)."""
    T_ref = reference_frame(day.sim)
    home = day.cell.home
    out: dict[str, list[float]] = {}

    def add(label: str, q: np.ndarray, T_user_tool: np.ndarray) -> None:
        placed, landed = placed_mm(day, q, T_ref @ T_user_tool)
        out.setdefault(label, []).append(placed)
        out.setdefault(f'{label}_landed', []).append(landed)

    swaps = {f'true_{s}': swapped_chain(day, s)
             for s in ('kinematics', 'tcp', 'user_frame', 'nominal_kinematics', 'nominal_tcp')}
    swaps['all_true'] = swapped_chain(day, 'all')
    active = rig_of(day.calibrated, day.cell, 'latest', day.model)
    adapter, T_base_user = active.chain('tcp'), active.T_base_user()
    for T in goals:
        for label, repo in (('nominal', day.nominal), ('calibrated', day.calibrated)):
            add(label, move.solve(day.cell, repo, T, home, frame='user').q, T)
        add('calibrated_adapter', _solved(adapter, T_base_user @ T, home), T)
        for label, (chain, T_bu) in swaps.items():
            add(label, _solved(chain, T_bu @ T, home), T)
    return {label: np.array(e) for label, e in out.items()}


def _solved(chain, T_base_tool: np.ndarray, home: np.ndarray) -> np.ndarray:
    result = rig.solve_target(chain, T_base_tool, home, home)
    if not result:
        raise benchlib.BenchFailed(f'a target cannot be reached: {result.message}')
    return result.q


def result_errors(day: FirstDay, goals: np.ndarray) -> Figures:
    """Each calibrated result against its truth."""
    name = day.model.name
    active = rig_of(day.calibrated, day.cell, 'latest', day.model)
    T_ref = reference_frame(day.sim)
    q = np.array([_solved(active.chain('tcp'), active.T_base_user() @ T, day.cell.home)
                  for T in goals])
    tool = day.sim.T_flange_tool_true
    calibrated_k = day.model.chain(active.active.kinematics.params, tool=tool)
    p_model = kinematics.fk(calibrated_k, q)[:, :3, 3]
    p_true = kinematics.fk(day.arm.true, q)[:, :3, 3]
    registered = frames.apply(register_rigid(p_model, p_true), p_model)
    k_err = np.linalg.norm(registered - p_true, axis=1)
    tcp_err = np.linalg.norm(active.tool('tcp')[:3, 3] - tool[:3, 3])
    D = frames.invert(T_ref) @ active.T_base_user()
    centre = day.cell.nominal_points_user().mean(axis=0)
    shift = np.linalg.norm(frames.apply(D, centre) - centre)
    angle = np.linalg.norm(Rotation.from_matrix(D[:3, :3]).as_rotvec())
    figures: Figures = {
        f'placement_{name}_kinematics_error_mm': (float(k_err.max() * 1e3), 'mm'),
        f'placement_{name}_tcp_error_mm': (float(tcp_err * 1e3), 'mm'),
        f'placement_{name}_user_frame_error_mm': (float(shift * 1e3), 'mm'),
        f'placement_{name}_user_frame_error_mrad': (float(angle * 1e3), 'mrad')}
    if hasattr(day, 'T_flange_optical'):
        distance, angle = frames.transform_error(day.T_flange_optical,
                                                 day.sim.camera.T_flange_optical)
        figures[f'placement_{name}_hand_eye_error_mm'] = (distance * 1e3, 'mm')
        figures[f'placement_{name}_hand_eye_error_mrad'] = (angle * 1e3, 'mrad')
    return figures


def run() -> Figures:
    figures: Figures = {}
    for name, cell in CELLS.items():
        sim = load_simulation(cell_file(cell))
        with tempfile.TemporaryDirectory() as root:
            day = FirstDay(sim, root)
            day.run()
            goals = targets(sim.cell, day.model, reference_frame(sim))
            for label, e in errors(day, goals).items():
                figures[f'placement_{name}_{label}_max_mm'] = (float(e.max()), 'mm')
                figures[f'placement_{name}_{label}_rms_mm'] = (
                    float(np.sqrt(np.mean(e ** 2))), 'mm')
            figures.update(result_errors(day, goals))
            for step, seconds in day.seconds.items():
                figures[f'placement_{name}_{step}_s'] = (seconds, 's')
        figures[f'placement_{name}_nominal_over_calibrated_rms'] = (
            figures[f'placement_{name}_nominal_rms_mm'][0]
            / figures[f'placement_{name}_calibrated_rms_mm'][0], '')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
