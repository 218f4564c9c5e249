"""The repeatability trial procedure on the one simulated robot (sim.robot), in-process: the
cell's true kinematics, table and markers, the nominal model for planning, the cell's noise."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core.repeatability.trial import Plan, ProbeRange, TrialError, TrialRun
from cobot_calib_ros.core.sensors.probe import Reading, ReadingStatus
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.trials import TrialStore

SIM = load_simulation(cell_file('sawyer_close'))
CELL = SIM.cell
PROBE_RANGE = ProbeRange(SIM.probe.min_range, SIM.probe.max_range)


def robot(seed: int, sim=SIM) -> DirectRobot:
    """The simulated arm read through the user's probe table (here: the true curve)."""
    return DirectRobot(SimRobot(sim, seed_offset=seed), sim.probe)


def _plan(method: str, cycles: int, axis: str = 'z', trial_id: str | None = None,
          cell=CELL) -> Plan:
    return Plan(trial_id or f'{method}-{axis}', method, axis, cell.layout, cell.markers, cycles,
                PROBE_RANGE)


def _run(tmp_path, method: str, cycles: int, seed: int = 3, axis: str = 'z'):
    store = TrialStore(tmp_path)
    return TrialRun(_plan(method, cycles, axis), robot(seed), store).start()


def test_reference_repeatability_matches_the_noise_model(tmp_path):
    """Unidirectional noise sigma per axis: the deviation |D| of a reading is half-normal, so
    RP_i -> sigma_i (sqrt(2/pi) + 3 sqrt(1 - 2/pi)) = 2.61 sigma_i, with sigma_i the cell's
    repeatability where marker i is."""
    trial = _run(tmp_path, 'reference', 30)
    from cobot_calib_ros.core.repeatability import point_statistics
    stats = point_statistics(trial.distances)
    assert trial.meta['status'] == 'done' and stats.cycles == 30
    factor = math.sqrt(2 / math.pi) + 3 * math.sqrt(1 - 2 / math.pi)    # 2.61
    sigma = np.array([SIM.repeatability_sigma_at(p) for p in SIM.world.true_points_base()])
    expected = factor * sigma.mean()
    assert 0.75 * expected < stats.rp_all < 1.25 * expected
    # F_i put every reading near the middle of the 0.2-2.2 mm range
    assert np.all(np.abs(trial.distances - 1.2e-3) < 0.2e-3)


def test_repeatability_grows_away_from_the_cell_centre():
    """sigma (1 + growth d^2): at the centre the cell's sigma, 0.3 m out 1 + 50 * 0.09 = 5.5x."""
    centre_user = np.array([0.25, 0.175, 0.02])
    corner_user = centre_user + [0.3, 0.0, 0.0]
    T = SIM.world.T_base_user
    at = [SIM.repeatability_sigma_at(T[:3, :3] @ p + T[:3, 3])
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
    wide = load_simulation(cell_file('sawyer_close'), 'wide')
    for method in ('reference', 'five_point_lsq'):
        close_rp = point_statistics(_run(tmp_path / method, method, 10).distances).rp_all
        plan = _plan(method, 10, trial_id=f'{method}-wide', cell=wide.cell)
        trial = TrialRun(plan, robot(3, wide), TrialStore(tmp_path / f'{method}-w')).start()
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
    run = TrialRun(_plan('rigid', 3, trial_id='t1'), robot(5), store,
                   on_reading=lambda c, i, d: readings.append((c, i)),
                   stop_requested=lambda: len(readings) >= 7)
    with pytest.raises(TrialError, match='resume') as stopped:
        run.start()
    assert stopped.value.reason == 'canceled'
    half = store.load('t1')
    assert half.meta['status'] == 'aborted' and half.resume == (1, 2)
    done = TrialRun(_plan('rigid', 3, trial_id='t1'), robot(6), store).resume(half)
    assert done.meta['status'] == 'done' and done.resume is None
    np.testing.assert_array_equal(done.distances[:, 0], half.distances[:, 0])
    assert np.all(np.isfinite(done.distances))


def test_out_of_range_reading_is_corrected_by_ff(tmp_path):
    """At one visit the robot lands 1.5 mm short, out of range: eq (15) moves 1 mm closer,
    reads again, and refers the reading back to the commanded point."""
    arm = robot(8)
    store = TrialStore(tmp_path)
    run = TrialRun(_plan('reference', 2, trial_id='ff'), arm, store)
    original_read, state = arm.read, {'n': 0}

    def read_short_at_one_visit():
        state['n'] += 1
        reading = original_read()
        if state['n'] not in (8, 9):      # after the 5 set-up readings: cycle 1, P3 (+ retry)
            return reading
        gap = SIM.world.probe_gap(arm.sim.true_tool()) + 1.5e-3
        return (Reading(math.nan, ReadingStatus.ABOVE_RANGE) if gap > SIM.probe.max_range
                else Reading(gap, ReadingStatus.OK))
    arm.read = read_short_at_one_visit
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
    arm = robot(1)
    with pytest.raises(TrialError, match=message):
        TrialRun(_plan(method, 2, axis), arm, TrialStore(tmp_path))
    assert arm.moves == 0
