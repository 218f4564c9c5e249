"""Compensated motion (issue 29, must-show 1): how close the tool gets to a pose target when the
suite solves it with the identified model, against the controller's nominal solve.

In-process, for the mock Sawyer, iiwa 7 and UR10e cells: the sim's sphere data over the
product's default sphere plan (bench_identification.sphere_data: the coupling self-centres on
the true spheres, joints averaged over 20 encoder readings), identified by CalibrationJob (as
`cobot-calib identify`), stored and activated in a scratch repository. Targets: 50 reachable
coupling poses in the calibrated volume and 50 over the workspace (core plans.tracker_plan,
seeds apart from the calibration's), each solved through api.move.solve (what `cobot-calib
move` sends to move_to as joints; robot_adapter solves with the same core.rig chain) with
``kinematics`` nominal and active, seeded at the configuration the target was drawn from (the
branch a program takes). Error: the true coupling centre at the solved joints (the
mock's truth: the sim's true model) against the target, in the robot's base frame, no
registration; the coupling is the tool the sphere calibration identifies.

- ``compensation_<robot>_{volume,workspace}_{nominal,compensated}_{max,rms}_mm`` [mm];
- ``..._compensated_registered_{max,rms}_mm``: the same in the calibrated model's own base
  (registered once to the true base over 200 other configurations: the base placement a sphere
  calibration cannot see, ``compensation_<robot>_base_offset_mm``, taken out);
- ``..._tcp_{nominal,compensated}_{max,rms}_mm``: targets for the cell's TCP (the sim's TCP is
  exactly the cell's; the calibration sees it only through the flange it identifies);
- ``..._compensated_region_registered_{max,rms}_mm``: the coupling registered over the region's
  own targets (the figure above registers once over the workspace: on the UR10e that base
  carries the workspace's extrapolation error into the volume);
- ``..._user_frame_{nominal,compensated}_{max,rms}_mm``: the region's TCP targets given in the
  user frame (a plant's program), solved through the nominal or the calibrated arm, each with
  the TCP and the user frame a perfect TCP calibration and perfect touches through that arm
  give (the kinematics alone, no touch noise), scored against the frame the true marker tops
  define (bench_placement.reference_frame);
- ``compensation_<robot>_workspace_ratio`` [1]: nominal max / compensated max over the
  workspace (goal >= 10; and compensated max <= 0.1 mm in the volume).
"""
from __future__ import annotations

import benchlib  # first: cobot_calib_ros before numpy (one BLAS thread), run alone too
import tempfile

import numpy as np

from benchlib import Figures
from bench_identification import sphere_data
from bench_placement import reference_frame
from cobot_calib_ros import store
from cobot_calib_ros.api import move
from cobot_calib_ros.core import frames, kinematics, rig, user_frame
from cobot_calib_ros.core.cell import tool_down_orientation
from cobot_calib_ros.core.tcp import solve_position
from cobot_calib_ros.core.tcp.touches import plan_touches, reachable_plan
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.identification import register_rigid
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob
from cobot_calib_ros.paths import cell_file, DEFAULT_CELL
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import KinematicRecord
from cobot_calib_ros.store.rigs import rig_of

CELLS = {'sawyer': DEFAULT_CELL, 'iiwa7': 'iiwa7_close', 'ur10e': 'ur10e_close'}
TARGETS = 50
SEEDS = {'volume': 10, 'workspace': 11}     # calibration plans draw from seeds 0..2
KINEMATICS = {'nominal': 'nominal', 'compensated': 'active'}
REGISTRATION, REGISTRATION_SEED = 200, 99


def calibrated_repository(robot: SimRobot, root) -> object:
    """A repository whose active kinematic calibration is identified on the sim's spheres."""
    outcome = CalibrationJob(robot.cell, robot.model, sphere_data(robot, robot.cell)).run()
    repo = store.open(root, cell=ResultsCell.of(robot.cell))
    activation = repo.kinematics.save_and_activate(KinematicRecord.from_outcome(outcome))
    if repo.kinematics.active(robot.model.name) is None:
        raise benchlib.BenchFailed(f'{robot.cell.name}: the calibration was not activated '
                                   f'({activation})')
    return repo


def registration(robot: SimRobot, repo) -> np.ndarray:
    """(4, 4) the calibrated model's base in the true one: the best rigid fit of its coupling
    centres to the true ones over REGISTRATION other workspace configurations (what a user frame
    touched with the calibrated arm absorbs; the sphere data cannot see it)."""
    calibrated = rig_of(repo, robot.cell, 'active', robot.model).chain('coupling')
    q = np.array([s['q'] for s in plans.tracker_plan(robot.cell, robot.model, 'workspace',
                                                      REGISTRATION, REGISTRATION_SEED)])
    return register_rigid(kinematics.fk(calibrated, q)[:, :3, 3],
                          kinematics.fk(robot.coupling, q)[:, :3, 3])


def errors_mm(robot: SimRobot, repo, region: str, T_true_model: np.ndarray
              ) -> dict[str, np.ndarray]:
    """|true tool - target| [mm] of each target: the coupling's {nominal, compensated,
    compensated_registered (in the calibrated model's base)}, and the TCP's
    {tcp_nominal, tcp_compensated}."""
    steps = plans.tracker_plan(robot.cell, robot.model, region, TARGETS, SEEDS[region])
    truth = {'coupling': robot.coupling, 'tcp': robot.true}
    errors: dict[str, list] = {}
    for step in steps:
        q0 = np.array(step['q'])
        for tool, prefix in (('coupling', ''), ('tcp', 'tcp_')):
            target = kinematics.fk(rig.Rig(robot.cell, model=robot.model).chain(tool), q0)
            for label, choice in KINEMATICS.items():
                solved = move.solve(robot.cell, repo, target, q0, tool=tool, kinematics=choice)
                reached = kinematics.fk(truth[tool], solved.q)[:3, 3]
                errors.setdefault(prefix + label, []).append(
                    np.linalg.norm(reached - target[:3, 3]) * 1e3)
                if tool == 'coupling' and label == 'compensated':
                    in_model = frames.apply(frames.invert(T_true_model), reached)
                    errors.setdefault('compensated_registered', []).append(
                        np.linalg.norm(in_model - target[:3, 3]) * 1e3)
    return {label: np.array(e) for label, e in errors.items()}


def user_frame_errors(robot: SimRobot, repo, region: str) -> dict[str, np.ndarray]:
    """|true tool - target| [mm] of the region's TCP targets given in the user frame, as a
    plant's program gives them: each target put in the base by the frame the TRUE marker tops
    define; solved through the nominal arm or the calibrated one, each with the TCP a perfect
    calibration through that arm finds (:func:`perfect_tcp`) and a user frame touched perfectly
    (the true tool exactly on the true marker tops) through that arm and TCP: this bench
    measures the kinematics, without the touch noise."""
    sim = robot.sim
    T_ref = reference_frame(sim)
    R = tool_down_orientation(sim.world.T_base_user, 'z')
    touches = np.array([_true_ik(robot, frames.make_transform(R, p))
                        for p in sim.world.true_points_base()])
    record = rig_of(repo, robot.cell, 'active', robot.model).active.kinematics
    errors: dict[str, list] = {}
    solving = {}
    for label, params in (('nominal', None), ('compensated', record.params)):
        chain = robot.model.chain(params, tool=perfect_tcp(robot, params))
        frame = user_frame.calibrate('rigid', robot.cell.nominal_points_user(),
                                     kinematics.fk(chain, touches)[:, :3, 3],
                                     max_rms_error=None).T_base_user
        solving[label] = chain, frame
    nominal_tcp = rig.Rig(robot.cell, model=robot.model).chain('tcp')
    for step in plans.tracker_plan(robot.cell, robot.model, region, TARGETS, SEEDS[region]):
        q0 = np.array(step['q'])
        T_user_tool = frames.invert(T_ref) @ kinematics.fk(nominal_tcp, q0)
        for label, (chain, frame) in solving.items():
            solved = rig.solve_target(chain, T_user_tool, q0, robot.cell.home, frame)
            reached = kinematics.fk(robot.true, solved.q)[:3, 3]
            errors.setdefault(f'user_frame_{label}', []).append(
                np.linalg.norm(reached - (T_ref @ T_user_tool)[:3, 3]) * 1e3)
    return {label: np.array(e) for label, e in errors.items()}


def _true_ik(robot: SimRobot, T_base_tool: np.ndarray) -> np.ndarray:
    """Joints that put the TRUE tool at ``T_base_tool``; BenchFailed when none."""
    result = kinematics.solve_ik_with_restarts(robot.true, T_base_tool, robot.cell.home,
                                               robot.cell.home)
    if not result:
        raise benchlib.BenchFailed(f'{robot.cell.name}: a perfect touch: {result.message}')
    return result.q


def perfect_tcp(robot: SimRobot, params) -> np.ndarray:
    """T_flange_tool (the cell tool's orientation) that the TCP calibration's default approaches
    of P1 (checked for reach, as tcp_calibrator plans them), touched exactly by the true tool,
    give through the arm ``params`` (None: nominal), by the solve's own position fit
    (core.tcp.solve_position); on the iiwa 7 it takes up d_7 / theta_7, which the sphere
    calibration leaves to the coupling."""
    name = robot.cell.point_names[0]
    point = frames.apply(robot.sim.world.T_base_user, robot.sim.world.marker(name).true_top)
    plan = reachable_plan(plan_touches(name), robot.true, point, robot.cell.home,
                          robot.cell.home)
    q = np.array([_true_ik(robot, frames.make_transform(R, point)) for R in plan.orientations])
    T = np.array(robot.cell.T_flange_tool, dtype=float)
    T[:3, 3] = solve_position(kinematics.fk(robot.model.chain(params), q)).t
    return T


def region_registered_mm(robot: SimRobot, repo, region: str) -> np.ndarray:
    """|true coupling - calibrated coupling| [mm] at the region's targets after the best rigid
    registration over those same targets (the base fitted where the error is measured)."""
    calibrated = rig_of(repo, robot.cell, 'active', robot.model).chain('coupling')
    q = np.array([s['q'] for s in plans.tracker_plan(robot.cell, robot.model, region,
                                                      TARGETS, SEEDS[region])])
    p = kinematics.fk(calibrated, q)[:, :3, 3]
    t = kinematics.fk(robot.coupling, q)[:, :3, 3]
    return np.linalg.norm(frames.apply(register_rigid(p, t), p) - t, axis=1) * 1e3


def run() -> Figures:
    figures: Figures = {}
    for name, cell in CELLS.items():
        robot = SimRobot(load_simulation(cell_file(cell)))
        with tempfile.TemporaryDirectory() as root:
            repo = calibrated_repository(robot, root)
            T_true_model = registration(robot, repo)
            figures[f'compensation_{name}_base_offset_mm'] = (
                float(np.linalg.norm(T_true_model[:3, 3]) * 1e3), 'mm')
            for region in SEEDS:
                measured = {**errors_mm(robot, repo, region, T_true_model),
                            **user_frame_errors(robot, repo, region),
                            'compensated_region_registered': region_registered_mm(
                                robot, repo, region)}
                for label, e in measured.items():
                    prefix = f'compensation_{name}_{region}_{label}'
                    figures[f'{prefix}_max_mm'] = (float(e.max()), 'mm')
                    figures[f'{prefix}_rms_mm'] = (float(np.sqrt(np.mean(e ** 2))), 'mm')
        figures[f'compensation_{name}_workspace_ratio'] = (
            figures[f'compensation_{name}_workspace_nominal_max_mm'][0]
            / figures[f'compensation_{name}_workspace_compensated_max_mm'][0], '')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
