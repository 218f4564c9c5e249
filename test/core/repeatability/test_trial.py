"""The repeatability trial procedure on a simulated cell (no ROS): the cell's true kinematics,
table and markers, the nominal model for planning, the cell's noise."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import kinematics
from cobot_calib_ros.store.trials import TrialStore
from cobot_calib_ros.core.repeatability.trial import Plan, ProbeRange, Reading, TrialError, TrialRun
from cobot_calib_ros.paths import cell_file

CELL = cellmod.load_cell(cell_file('sawyer_close'))


class SimRobot:
    """What mock_robot does, in-process: plans with the nominal model, lands on the true one."""

    def __init__(self, cell: cellmod.Cell, seed: int) -> None:
        model = kinematics.model_by_name(cell.robot)
        true = cellmod.true_parameters(cell, model.nominal, model.parameter_names)
        self.nominal = model.chain(tool=cell.tool_offset)
        self.true = model.chain(true, tool=cell.tool_offset)
        self.cell, self.rng = cell, np.random.default_rng(seed)
        self.q = cell.home.copy()
        self.T_true = kinematics.fk(self.true, self.q)
        self.moves = 0

    def _go(self, chain, T) -> None:
        result = kinematics.solve_ik_with_restarts(chain, T, self.q, self.cell.home)
        if not result.success:
            raise TrialError('motion', result.message)
        self.q = result.q
        self.T_true = kinematics.fk(self.true, self.q)
        sigma = cellmod.repeatability_sigma_at(self.cell, self.T_true[:3, 3])
        self.T_true[:3, 3] += self.rng.normal(0.0, sigma, 3)
        self.moves += 1

    def touch(self, name: str) -> np.ndarray:
        world = self.cell.world
        T = np.eye(4)
        T[:3, :3] = cellmod.tool_down_orientation(world.T_base_user)
        T[:3, 3] = world.T_base_user[:3, :3] @ world.marker(name).true_top \
            + world.T_base_user[:3, 3] + self.rng.normal(0.0, self.cell.noise.touch_sigma, 3)
        self._go(self.true, T)
        return kinematics.fk(self.nominal, self.q)

    def move(self, T: np.ndarray) -> None:
        self._go(self.nominal, T)

    def read(self) -> Reading:
        gap = self.cell.world.probe_gap(self.T_true) + self.rng.normal(0.0, 5e-7)
        if gap < self.cell.probe.min_range:
            return Reading('below', math.nan)
        if gap > self.cell.probe.max_range:
            return Reading('above', math.nan)
        return Reading('ok', gap)


def _plan(method: str, cycles: int, axis: str = 'z', trial_id: str | None = None) -> Plan:
    markers = [CELL.world.marker(n) for n in CELL.world.point_names]
    return Plan(trial_id or f'{method}-{axis}', method, axis, CELL.layout, markers, cycles,
                ProbeRange(CELL.probe.min_range, CELL.probe.max_range))


def _run(tmp_path, method: str, cycles: int, seed: int = 3, axis: str = 'z'):
    store = TrialStore(tmp_path)
    return TrialRun(_plan(method, cycles, axis), SimRobot(CELL, seed), store).start()


def test_reference_repeatability_matches_the_noise_model(tmp_path):
    """Unidirectional noise sigma per axis: the deviation |D| of a reading is half-normal, so
    RP_i -> sigma_i (sqrt(2/pi) + 3 sqrt(1 - 2/pi)) = 2.61 sigma_i, with sigma_i the cell's
    repeatability where marker i is."""
    trial = _run(tmp_path, 'reference', 12)
    from cobot_calib_ros.core.repeatability import point_statistics
    stats = point_statistics(trial.distances)
    assert trial.meta['status'] == 'done' and stats.cycles == 12
    factor = math.sqrt(2 / math.pi) + 3 * math.sqrt(1 - 2 / math.pi)
    assert factor == pytest.approx(2.61, abs=0.005)
    sigma = np.array([cellmod.repeatability_sigma_at(CELL, p)
                      for p in CELL.world.true_points_base()])
    expected = factor * sigma.mean()
    assert 1.8e-5 * factor < expected < 3.6e-5 * factor       # close layout: near the centre
    assert 0.5 * expected < stats.rp_all < 1.6 * expected
    # F_i put every reading near the middle of the 0.2-2.2 mm range
    assert np.all(np.abs(trial.distances - 1.2e-3) < 0.2e-3)


def test_repeatability_grows_away_from_the_cell_centre():
    """sigma (1 + growth d^2): at the centre the cell's sigma, 0.3 m out 1 + 50 * 0.09 = 5.5x."""
    centre_user = np.array([0.25, 0.175, 0.02])
    corner_user = centre_user + [0.3, 0.0, 0.0]
    T = CELL.world.T_base_user
    at = [cellmod.repeatability_sigma_at(CELL, T[:3, :3] @ p + T[:3, 3])
          for p in (centre_user, corner_user)]
    assert at == pytest.approx([1.8e-5, 1.8e-5 * 5.5])


def test_methods_order_as_in_the_paper(tmp_path):
    """reference <= five-point <= three-point (paper Table 4)."""
    from cobot_calib_ros.core.repeatability import point_statistics
    rp = {m: point_statistics(_run(tmp_path / m, m, 15).distances).rp_all
          for m in ('reference', 'five_point_lsq', 'three_point')}
    assert rp['reference'] < rp['five_point_lsq'] < rp['three_point'], rp


def test_the_wide_set_up_repeats_worse_than_the_close_one(tmp_path):
    """Paper Tables 4-5: every method's RP_all grows from close to wide."""
    from cobot_calib_ros.core.repeatability import point_statistics
    wide = cellmod.load_cell(cell_file('sawyer_close'), 'wide')
    for method in ('reference', 'five_point_lsq'):
        close_rp = point_statistics(_run(tmp_path / method, method, 10).distances).rp_all
        markers = [wide.world.marker(n) for n in wide.world.point_names]
        plan = Plan(f'{method}-wide', method, 'z', 'wide', markers, 10,
                    ProbeRange(wide.probe.min_range, wide.probe.max_range))
        trial = TrialRun(plan, SimRobot(wide, 3), TrialStore(tmp_path / f'{method}-w')).start()
        assert point_statistics(trial.distances).rp_all > 1.5 * close_rp, method


@pytest.mark.parametrize('method, axis', [('reference', 'x'), ('rigid', 'x'), ('rigid', 'y')])
def test_side_face_axis_reads_in_range(tmp_path, method, axis):
    """The probe turned horizontal at a marker's side face (the wrist turns a lot)."""
    trial = _run(tmp_path, method, 3, axis=axis)
    assert np.all(np.isfinite(trial.distances))
    assert np.all(np.abs(trial.distances - 1.2e-3) < 0.2e-3)


def test_stop_then_resume_completes_without_losing_readings(tmp_path):
    store = TrialStore(tmp_path)
    readings = []
    run = TrialRun(_plan('rigid', 3, trial_id='t1'), SimRobot(CELL, 5), store,
                   on_reading=lambda c, i, d: readings.append((c, i)),
                   stop_requested=lambda: len(readings) >= 7)
    with pytest.raises(TrialError, match='resume') as stopped:
        run.start()
    assert stopped.value.reason == 'canceled'
    half = store.load('t1')
    assert half.meta['status'] == 'aborted' and half.resume == (1, 2)
    done = TrialRun(_plan('rigid', 3, trial_id='t1'), SimRobot(CELL, 6), store).resume(half)
    assert done.meta['status'] == 'done' and done.resume is None
    np.testing.assert_array_equal(done.distances[:, 0], half.distances[:, 0])
    assert np.all(np.isfinite(done.distances))


def test_out_of_range_reading_is_corrected_by_ff(tmp_path):
    """At one visit the robot lands 1.5 mm short, out of range: eq (15) moves 1 mm closer,
    reads again, and refers the reading back to the commanded point."""
    robot = SimRobot(CELL, 8)
    store = TrialStore(tmp_path)
    run = TrialRun(_plan('reference', 2, trial_id='ff'), robot, store)
    original_read, state = robot.read, {'n': 0}

    def read_short_at_one_visit():
        state['n'] += 1
        reading = original_read()
        if state['n'] not in (8, 9):      # after the 5 set-up readings: cycle 1, P3 (+ retry)
            return reading
        gap = CELL.world.probe_gap(robot.T_true) + 1.5e-3
        return Reading('above', math.nan) if gap > CELL.probe.max_range else Reading('ok', gap)
    robot.read = read_short_at_one_visit
    trial = run.start()
    rows = (tmp_path / 'trials' / 'ff' / 'distances.csv').read_text().splitlines()
    corrected = [r.split(',') for r in rows[1:] if 'closer' in r]
    assert len(corrected) == 1 and corrected[0][2] == 'P3'
    raw, ff = float(corrected[0][3]), float(corrected[0][4])
    assert ff == pytest.approx(1.0e-3)
    assert raw == pytest.approx(1.2e-3 - 1.0e-3 + 1.5e-3, abs=2e-4)
    assert trial.distances[2, 0] == pytest.approx(raw + ff)    # 2.7 mm: the short landing


@pytest.mark.parametrize('method, axis, message', [
    ('four_point', 'z', 'unknown method'), ('rigid', 'w', 'unknown axis')])
def test_bad_plans_are_refused_before_moving(tmp_path, method, axis, message):
    robot = SimRobot(CELL, 1)
    with pytest.raises(TrialError, match=message):
        TrialRun(_plan(method, 2, axis), robot, TrialStore(tmp_path))
    assert robot.moves == 0
