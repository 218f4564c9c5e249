"""Planned kinematic calibration (issue 20): fewer poses, a predicted accuracy, a stopping rule.

In-process on the pure core and the simulation (no ROS): core.kinematics.planning.SpherePlanner
chooses each pose, sim.robot.DirectRobot (the RobotPort of the in-process tests) couples the
mock iiwa 7 of config/cells/iiwa7_close.yaml (the paper's Table 6 deviations, 3 um coupling
noise) to the true spheres and averages the joints over the hold, the planner refits and
predicts. The collection over ROS runs the same core loop over RobotCalls; what the nodes add
(DDS round trips) is not what this measures.

Held-out error: 125 laser-tracker configurations in the calibrated volume (plans.tracker_plan
'volume', seed 0), the identified model against the true robot after the best rigid
registration, max [mm]; also as the simulated tracker measures them (25 um per axis), where the
tracker's own noise dominates. The planner's task volume is another draw of the same region
(seed 1). Compared:

- full: the paper's 3 x 625 grid, every pose;
- planned: core.kinematics.planned_collection.collect_planned (the loop the node runs) with
  greedy V-optimal choice from the candidate pool (planning.sphere_candidates: tilt -60..60
  deg, a full turn about the approach axis, arm angle -150..150 deg, all in 30 deg steps,
  and the flipped configurations), re-planned after every pose, up to 100 poses; the
  greedy order (PlanSettings.exchange off), the one a --target-mm run takes;
- random: 20 draws of the same size from the same pool;
- target: where ``--target-mm`` at 1.2x the full grid's predicted max (predicted with the
  noise this run estimated; no truth used) would have stopped the same planned run.
- seeds: full and planned again on five more noise draws of the sim robot, each with its own
  full grid: one run's error ratio scatters by about +-25 %, so one draw is not the answer.

Robot time: DirectRobot's (moves at 1 rad/s on the largest joint step, as mock_robot reports
them, plus holds), and the same moves with the paper's 1 s hold.

Issue 38.5, ``planned_50_<robot>_*`` (iiwa7: this cell; ur10e: config/cells/ur10e_close.yaml):
the planned collection as ``identify --planned`` runs it by default (50 poses), on six noise
draws of the sim robot (PLANNED_50_SEEDS), each its own full grid beside it: poses, robot time
at the paper's hold, held-out max over the full grid's on the same draw
(``over_full_max_error_ratio``) and in expectation (``mean_over_full_mean_max_error_ratio``:
PLANNED_50_REPEATS re-collections of each draw's 50 planned poses over the mean of the six
grids; one draw of the grid's max scattered 1.2-4.3 um on the UR10e), the same over the
grid's own expectation (``mean_over_full_expected_max_error_ratio``: the grid re-collected
PLANNED_50_REPEATS times; on the iiwa 7 the six draws' mean, 1.044 um, is 11 % under that,
1.174 um, and 18 % under 40 more re-collections offline, 1.271 um), and each
draw's last prediction against its planned poses' expected held-out max; medians over the
draws and the worst. ``--planned-50`` runs this part alone.
"""
from __future__ import annotations

from dataclasses import dataclass
import sys
import time

import numpy as np

import benchlib
from benchlib import Figures
from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.kinematics import plans
from cobot_calib_ros.core.kinematics.identification import (register_rigid,
                                                            SphereObservations)
from cobot_calib_ros.core.kinematics.kinematic_calibration import fit_spheres
from cobot_calib_ros.core.kinematics.planned_collection import collect_planned, RobotTime
from cobot_calib_ros.core.kinematics.planning import (PlanSettings, Prediction,
                                                      sphere_candidates, SpherePlanner)
from cobot_calib_ros.core.robot_port import MoveFailed
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

CELL = 'iiwa7_close'
HOLD = 0.02                 # [s] as the fast mock collection
PAPER_HOLD = 1.0            # [s]
MAX_POSES = 100
RANDOM_DRAWS = 20
CHECKPOINTS = (30, 60, 100)
REPEATS = 10                # re-collections of the planned poses for the measured mean
TARGET_OVER_FULL = 1.2      # a --target-mm of 1.2x the full grid's predicted max
SEED = 1000                 # the sim robot's noise seed (SimRobot's default)
MORE_SEEDS = (1100, 1200, 1300, 1400, 1500)     # the same comparison on other noise draws
# issue 38.5: the planned collection stopped at 50 poses, on these robots' cells
PLANNED_50_CELLS = {'iiwa7': CELL, 'ur10e': 'ur10e_close'}
PLANNED_50_SEEDS = (SEED, *MORE_SEEDS)      # noise draws, each its own grid and planned run
PLANNED_50_REPEATS = 30     # re-collections of each draw's planned poses: the draws plan the
#                             same 50 (the set is planned before any data), and ten gave the
#                             UR10e's one expectation as 1.69-2.51 um across the six draws


class Bench:
    def __init__(self, seed_offset: int = SEED, cell: str = CELL) -> None:
        self.sim = load_simulation(cell_file(cell))
        self.robot = SimRobot(self.sim, seed_offset=seed_offset)
        self.cell, self.model = self.sim.cell, self.robot.model
        self.port = DirectRobot(self.robot, self.sim.probe)
        self.distances = self.cell.spheres.known_distances()
        self.tool0 = self.cell.spheres.T_flange_coupling[:3, 3].copy()
        held = plans.tracker_plan(self.cell, self.model, 'volume', plans.TRACKER_CONFIGS, 0)
        self.q_held = np.array([s['q'] for s in held])
        task = plans.tracker_plan(self.cell, self.model, 'volume', plans.TRACKER_CONFIGS, 1)
        self.q_task = np.array([s['q'] for s in task])
        self.p_true = kinematics.fk(self.robot.coupling, self.q_held)[:, :3, 3]
        rng = np.random.default_rng(11)
        self.p_tracker = self.p_true + rng.normal(0.0, self.sim.spheres.tracker.sigma,
                                                  self.p_true.shape)

    def measure(self, steps, count: int = 0) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Visit steps on the sim through DirectRobot until ``count`` are measured (0: all),
        skipping those the coupling cannot reach (as the collection does): joints, targets,
        robot time [s] and the same at the paper's hold."""
        start = self.port.robot_seconds
        q, target = [], []
        for step in steps:
            try:
                self.port.move_joints(np.asarray(step['q']), compliant=True)
            except MoveFailed:
                continue
            q.append(self.port.capture(HOLD).q)
            target.append(step['target'])
            if len(q) == count:
                break
        seconds = self.port.robot_seconds - start
        return (np.array(q), np.array(target), seconds,
                seconds + len(q) * (PAPER_HOLD - HOLD))

    def held_out_mm(self, params, p_flange_tool) -> tuple[float, float]:
        """Max error [mm] at the held-out configurations: against the truth, and against the
        tracker's readings."""
        tool = frames.make_transform(np.eye(3), p_flange_tool)
        p = kinematics.fk(self.model.chain(params, tool), self.q_held)[:, :3, 3]
        out = []
        for reference in (self.p_true, self.p_tracker):
            fitted = frames.apply(register_rigid(p, reference), p)
            out.append(float(np.linalg.norm(fitted - reference, axis=1).max() * 1e3))
        return out[0], out[1]

    def identify_mm(self, parameter_set, q, target) -> tuple[float, float]:
        data = SphereObservations(q, target, self.distances)
        params, p_flange_tool, _ = fit_spheres(self.model, data, self.tool0, parameter_set.free)
        return self.held_out_mm(params, p_flange_tool)


@dataclass
class Compared:
    """The full grid and the planned collection on one sim robot (one noise draw)."""

    planner: SpherePlanner
    robot_time: RobotTime           # the planned collection's
    moves: np.ndarray               # each planned pose's move [s]
    estimates: list                 # (params, p_flange_tool) after each planned pose
    measured: dict                  # checkpoint -> (prediction, held-out max [mm] x2)
    q_full: np.ndarray
    t_full: np.ndarray
    full_s: float                   # robot time of the grid at HOLD [s]
    full_paper_s: float             # ... at the paper's hold [s]
    full_truth: float               # held-out max against the true robot [mm]
    full_tracker: float             # ... against the tracker's readings [mm]
    full_predicted: Prediction      # the grid's, at this run's final estimate and noise

    def target_stop(self, bench: Bench, ratio: float) -> tuple[int, float, float]:
        """Where --target-mm at ``ratio`` x the full grid's predicted max (the noise this run
        estimated; no truth used) stops this run: poses, robot time at the paper's hold [s],
        held-out max [mm]."""
        target = ratio * self.full_predicted.max_m * 1e3
        curve = [p.max_m * 1e3 for p in self.planner.state.predictions]
        k = next((k for k, v in enumerate(curve) if v <= target), len(curve) - 1)
        seconds = float(np.sum(self.moves[:k + 1]) + (k + 1) * PAPER_HOLD)
        return k + 1, seconds, bench.held_out_mm(*self.estimates[k])[0]


def compare(bench: Bench, grid, pool, parameter_set=None) -> Compared:
    """Collect the full grid, then the planned collection, on ``bench``'s robot."""
    # the greedy order (exchange off): the one a --target-mm run takes, which target_stop
    # reads off this run's prediction curve
    planner = SpherePlanner(bench.model, pool, bench.distances, bench.tool0, bench.q_task,
                            PlanSettings(max_poses=MAX_POSES, pose_seconds=PAPER_HOLD,
                                         exchange=False),
                            parameter_set=parameter_set)
    q_full, t_full, full_s, full_paper_s = bench.measure(grid)
    full_truth, full_tracker = bench.identify_mm(planner.parameter_set, q_full, t_full)
    measured, seconds, estimates = {}, [], []

    def on_pose(record, capture, run, prediction) -> None:
        seconds.append(bench.port.robot_seconds)
        estimates.append((planner.params.copy(), planner.p_flange_tool.copy()))
        if run.recorded in CHECKPOINTS:
            measured[run.recorded] = (prediction, bench.held_out_mm(planner.params,
                                                                    planner.p_flange_tool))
    before = bench.port.robot_seconds
    _, robot_time = collect_planned(planner, bench.port, lambda record: None, hold=HOLD,
                                    on_pose=on_pose)
    print(f'planned collection stopped: {planner.state.stop}', file=sys.stderr)
    moves = np.diff(np.r_[before, seconds]) - HOLD
    return Compared(planner, robot_time, moves, estimates, measured, q_full, t_full, full_s,
                    full_paper_s, full_truth, full_tracker, planner.predict_for(q_full, t_full))


def run() -> Figures:
    start = time.perf_counter()
    bench = Bench()
    grid, _ = plans.sphere_plan(bench.cell, bench.model)
    pool, _ = sphere_candidates(bench.cell, bench.model)
    c = compare(bench, grid, pool)
    planner, n = c.planner, len(c.planner.q)
    figures: Figures = {'planning_candidates': (float(len(pool)), 'poses'),
                        'full_poses': (float(len(c.q_full)), 'poses')}
    planned_truth, planned_tracker = bench.held_out_mm(planner.params, planner.p_flange_tool)
    rng = np.random.default_rng(3)
    random_truth = []
    for _ in range(RANDOM_DRAWS):
        q, t, _, _ = bench.measure([pool[i] for i in rng.permutation(len(pool))], n)
        random_truth.append(bench.identify_mm(planner.parameter_set, q, t)[0])
    full_predicted = c.full_predicted
    reach, reach_s, _ = c.target_stop(bench, 1.0)
    k, target_s, target_truth = c.target_stop(bench, TARGET_OVER_FULL)
    planned_s = c.robot_time.at_hold(PAPER_HOLD)
    figures.update({
        'target_1p2_full_predicted_um': (TARGET_OVER_FULL * full_predicted.max_m * 1e3 * 1e3, 'um'),
        'target_1p2_poses': (float(k), 'poses'),
        'target_1p2_heldout_max_um': (target_truth * 1e3, 'um'),
        'target_1p2_over_full_max_error_ratio': (target_truth / c.full_truth, 'x'),
        'target_1p2_robot_s': (target_s, 's'),
        'full_over_target_1p2_robot_time': (c.full_paper_s / target_s, 'x')})
    figures.update({
        'planned_poses': (float(n), 'poses'),
        'full_heldout_max_um': (c.full_truth * 1e3, 'um'),
        'planned_heldout_max_um': (planned_truth * 1e3, 'um'),
        'planned_over_full_max_error_ratio': (planned_truth / c.full_truth, 'x'),
        'full_tracker_max_um': (c.full_tracker * 1e3, 'um'),
        'planned_tracker_max_um': (planned_tracker * 1e3, 'um'),
        'planned_over_full_tracker_max_error_ratio': (planned_tracker / c.full_tracker, 'x'),
        'random_median_heldout_max_um': (float(np.median(random_truth)) * 1e3, 'um'),
        'random_worst_heldout_max_um': (float(np.max(random_truth)) * 1e3, 'um'),
        'planned_over_random_median_ratio': (planned_truth / float(np.median(random_truth)),
                                             'x'),
        'planned_over_random_worst_ratio': (planned_truth / float(np.max(random_truth)), 'x'),
        'planned_robot_s': (planned_s, 's'),
        'full_robot_s': (c.full_paper_s, 's'),
        'full_over_planned_robot_time': (c.full_paper_s / planned_s, 'x'),
        'planned_robot_s_fast_hold': (c.robot_time.total, 's'),
        'full_robot_s_fast_hold': (c.full_s, 's'),
        'full_predicted_max_um': (full_predicted.max_m * 1e3 * 1e3, 'um'),
        'planned_poses_to_full_predicted': (float(reach), 'poses'),
        'planned_robot_s_to_full_predicted': (reach_s, 's'),
    })
    means = recollected_means(bench, planner, sorted({*c.measured, k}))
    figures.update(prediction_figures(c.measured, means))
    seeds, full_draws = seed_figures(grid, pool, planner.parameter_set)
    figures.update(seeds)
    # expected values: one draw's max scatters by +-25 % and more (seed figures)
    full_mean = float(np.mean([c.full_truth, *full_draws]))
    figures.update({
        'full_mean_heldout_max_um': (full_mean * 1e3, 'um'),
        'full_draws': (float(1 + len(full_draws)), 'draws'),
        'planned_mean_over_full_mean_max_error_ratio': (means[max(CHECKPOINTS)] / full_mean,
                                                        'x'),
        'target_1p2_mean_heldout_max_um': (means[k] * 1e3, 'um'),
        'target_1p2_mean_over_full_mean_max_error_ratio': (means[k] / full_mean, 'x')})
    for robot, cell in PLANNED_50_CELLS.items():
        figures.update(planned_50_figures(robot, cell, *((grid, pool) if cell == CELL else ())))
    figures['planning_bench_seconds'] = (time.perf_counter() - start, 's')
    return figures


def planned_50_figures(robot: str, cell: str, grid=None, pool=None) -> Figures:
    """The planned collection as `identify --planned` runs it (the default settings: 50 poses)
    against the full grid, on PLANNED_50_SEEDS fresh noise draws of ``cell``'s sim robot,
    each draw its own grid and planned collection: poses, robot time at the paper's hold,
    held-out max over the full grid's on the same draw; expected (the mean of REPEATS
    re-collections of each draw's planned poses over the mean of the draws' grids); and each
    draw's last prediction against its planned poses' expected held-out max. Medians over
    the draws, and the worst."""
    if grid is None:
        bench = Bench(SEED, cell)
        grid, _ = plans.sphere_plan(bench.cell, bench.model)
        pool, _ = sphere_candidates(bench.cell, bench.model)
    rows = []
    for seed in PLANNED_50_SEEDS:
        bench = Bench(seed, cell)
        planner = SpherePlanner(bench.model, pool, bench.distances, bench.tool0, bench.q_task,
                                PlanSettings(pose_seconds=PAPER_HOLD))
        q_full, t_full, _, _ = bench.measure(grid)
        full = bench.identify_mm(planner.parameter_set, q_full, t_full)[0]
        _, robot_time = collect_planned(planner, bench.port, lambda record: None, hold=HOLD)
        n = len(planner.q)
        planned = bench.held_out_mm(planner.params, planner.p_flange_tool)[0]
        # each draw's re-collections their own noise (the draws often choose the same poses)
        planned_mean = recollected_means(bench, planner, [n], 10 * seed,
                                         PLANNED_50_REPEATS)[n]
        full_predicted = planner.predict_for(q_full, t_full).max_m * 1e3
        rows.append((n, robot_time.at_hold(PAPER_HOLD), planned, full, planned_mean,
                     planner.state.predictions[-1].max_m * 1e3, full_predicted))
        print(f'planned_50 {robot} seed {seed}: {n} poses, {rows[-1][1]:.1f} s, held-out '
              f'max planned {planned * 1e3:.3f} um, full {full * 1e3:.3f} um, planned '
              f'expected {planned_mean * 1e3:.3f} um, predicted {rows[-1][5] * 1e3:.3f} um '
              f'(full grid predicted {full_predicted * 1e3:.3f} um)', file=sys.stderr)
    r = np.array(rows)
    full_mean = float(np.mean(r[:, 3]))
    single, expected = r[:, 2] / r[:, 3], r[:, 4] / full_mean
    prediction = (r[:, 5] / r[:, 4] - 1.0) * 100.0
    # the grid's expectation itself: six draws' mean scatters by +-14 % (one draw's max by
    # +-35 %), more than the goal's margin
    full_expected = recollected_grid_mean(bench, grid, planner.parameter_set, 100000)
    name = f'planned_50_{robot}_'
    return {
        name + 'full_expected_heldout_max_um': (full_expected * 1e3, 'um'),
        name + 'mean_over_full_expected_max_error_ratio': (
            float(np.median(r[:, 4])) / full_expected, 'x'),
        name + 'mean_over_full_expected_max_error_ratio_worst': (
            float(np.max(r[:, 4])) / full_expected, 'x'),
        name + 'draws': (float(len(r)), 'draws'),
        name + 'poses': (float(np.max(r[:, 0])), 'poses'),
        name + 'robot_s': (float(np.median(r[:, 1])), 's'),
        name + 'robot_s_worst': (float(np.max(r[:, 1])), 's'),
        name + 'full_mean_heldout_max_um': (full_mean * 1e3, 'um'),
        name + 'mean_heldout_max_um': (float(np.median(r[:, 4])) * 1e3, 'um'),
        name + 'over_full_max_error_ratio': (float(np.median(single)), 'x'),
        name + 'over_full_max_error_ratio_worst': (float(np.max(single)), 'x'),
        name + 'mean_over_full_mean_max_error_ratio': (float(np.median(expected)), 'x'),
        name + 'mean_over_full_mean_max_error_ratio_worst': (float(np.max(expected)), 'x'),
        name + 'predicted_over_full_predicted_ratio': (float(np.median(r[:, 5] / r[:, 6])),
                                                       'x'),
        name + 'prediction_error_percent': (float(np.median(prediction)), '%'),
        name + 'prediction_error_percent_worst': (float(prediction[np.argmax(np.abs(
            prediction))]), '%')}


def seed_figures(grid, pool, parameter_set) -> tuple[Figures, list[float]]:
    """The same comparison on MORE_SEEDS noise draws of the sim robot (each its own full grid
    and planned collection): how the single-run ratios scatter; and each draw's full grid
    held-out max [mm]."""
    rows, full = [], []
    for seed in MORE_SEEDS:
        bench = Bench(seed)
        c = compare(bench, grid, pool, parameter_set)
        planned = bench.held_out_mm(c.planner.params, c.planner.p_flange_tool)[0]
        full.append(c.full_truth)
        k, seconds, truth = c.target_stop(bench, TARGET_OVER_FULL)
        rows.append((c.full_paper_s / c.robot_time.at_hold(PAPER_HOLD),
                     planned / c.full_truth, k, c.full_paper_s / seconds, truth / c.full_truth))
    r = np.array(rows)
    meeting = np.sum((r[:, 3] >= 18.0) & (r[:, 4] <= TARGET_OVER_FULL))
    print('seeds (full / planned robot time, planned / full max error; target_1p2 poses, '
          'full / its robot time, its / full max error): ' + '; '.join(
              f'{s}: {a:.2f}x {b:.2f}x, {k:.0f} {c:.2f}x {d:.2f}x'
              for s, (a, b, k, c, d) in zip(MORE_SEEDS, rows)), file=sys.stderr)
    return {
        'seeds': (float(len(MORE_SEEDS)), 'draws'),
        'seeds_full_over_planned_robot_time_median': (float(np.median(r[:, 0])), 'x'),
        'seeds_planned_over_full_max_error_ratio_median': (float(np.median(r[:, 1])), 'x'),
        'seeds_planned_over_full_max_error_ratio_worst': (float(np.max(r[:, 1])), 'x'),
        'seeds_target_1p2_poses_median': (float(np.median(r[:, 2])), 'poses'),
        'seeds_full_over_target_1p2_robot_time_median': (float(np.median(r[:, 3])), 'x'),
        'seeds_full_over_target_1p2_robot_time_worst': (float(np.min(r[:, 3])), 'x'),
        'seeds_target_1p2_over_full_max_error_ratio_median': (float(np.median(r[:, 4])), 'x'),
        'seeds_target_1p2_over_full_max_error_ratio_worst': (float(np.max(r[:, 4])), 'x'),
        'seeds_target_1p2_meeting_18x_and_1p2': (float(meeting), 'draws')}, full


def recollected_means(bench: Bench, planner: SpherePlanner, counts,
                      first_seed: int = 2000, repeats: int = REPEATS) -> dict[int, float]:
    """The expected held-out max [mm] of the first ``count`` planned poses, for each of
    ``counts``: the mean over ``repeats`` re-collections of them with fresh noise (the sim
    robot's seed offsets from ``first_seed``)."""
    chosen = [planner.candidates[i] for i in planner.state.chosen]
    values = {count: [] for count in counts}
    for seed in range(repeats):
        port = DirectRobot(SimRobot(bench.sim, seed_offset=first_seed + seed),
                           bench.sim.probe)
        q = []
        for step in chosen:
            port.move_joints(np.asarray(step['q']), compliant=True)
            q.append(port.capture(HOLD).q)
        for count in values:
            data = SphereObservations(np.array(q[:count]),
                                      np.array([s['target'] for s in chosen[:count]]),
                                      bench.distances)
            params, p_flange_tool, _ = fit_spheres(bench.model, data, bench.tool0,
                                              planner.parameter_set.free)
            values[count].append(bench.held_out_mm(params, p_flange_tool)[0])
    return {count: float(np.mean(v)) for count, v in values.items()}


def recollected_grid_mean(bench: Bench, grid, parameter_set, first_seed: int,
                          repeats: int = PLANNED_50_REPEATS) -> float:
    """The full grid's expected held-out max [mm]: the mean over ``repeats`` collections
    of it with fresh noise (the sim robot's seed offsets from ``first_seed``)."""
    port, values = bench.port, []
    for seed in range(repeats):
        bench.port = DirectRobot(SimRobot(bench.sim, seed_offset=first_seed + seed),
                                 bench.sim.probe)
        q, target, _, _ = bench.measure(grid)
        values.append(bench.identify_mm(parameter_set, q, target)[0])
    bench.port = port
    return float(np.mean(values))


def prediction_figures(measured: dict, means: dict[int, float]) -> Figures:
    """Predicted against measured held-out max at the checkpoints: the measured once (this
    run) and the expected (:func:`recollected_means`; the prediction is of the expected max
    over noise realisations)."""
    figures: Figures = {}
    for count, (prediction, (truth, _)) in sorted(measured.items()):
        mean = means[count]
        figures[f'predicted_max_um_at_{count}'] = (prediction.max_m * 1e3 * 1e3, 'um')
        figures[f'measured_max_um_at_{count}'] = (truth * 1e3, 'um')
        figures[f'measured_mean_max_um_at_{count}'] = (mean * 1e3, 'um')
        figures[f'prediction_error_percent_at_{count}'] = (
            (prediction.max_m * 1e3 / mean - 1.0) * 100.0, '%')
        figures[f'prediction_error_percent_this_run_at_{count}'] = (
            (prediction.max_m * 1e3 / truth - 1.0) * 100.0, '%')
    return figures


def run_planned_50() -> Figures:
    """The planned_50 figures alone (``--planned-50``)."""
    start, figures = time.perf_counter(), {}
    for robot, cell in PLANNED_50_CELLS.items():
        figures.update(planned_50_figures(robot, cell))
    figures['planning_bench_seconds'] = (time.perf_counter() - start, 's')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run_planned_50 if '--planned-50' in sys.argv[1:] else run))
