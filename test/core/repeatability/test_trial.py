"""The repeatability trial procedure on the one simulated robot (sim.robot), in-process: the
cell's true kinematics, table and markers, the nominal model for planning, the cell's noise."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core import user_frame
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.repeatability import AXES
from cobot_calib_ros.core.repeatability.trial import (
    goal_problem, LandmarkRig, METHODS, Plan, PortRobot, ProbeRange, resume_problem, retreat,
    TrialError, TrialRun)
from cobot_calib_ros.core.sensors.probe import Reading, ReadingStatus
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation
from cobot_calib_ros.store.trials import TrialStore

SIM = load_simulation(cell_file('sawyer_close'))
CELL = SIM.cell
PROBE_RANGE = ProbeRange(SIM.probe.min_range, SIM.probe.max_range)


CAPTURE_DURATION = 0.3     # [s] repeatability_trial's default


def robot(seed: int, sim=SIM) -> PortRobot:
    """The simulated arm read through the user's probe table (here: the true curve), driven
    on the nominal model; landmark frames from its wrist camera with the nominal hand-eye."""
    from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
    arm = SimRobot(sim, seed_offset=seed)
    cell, model = sim.cell, arm.model
    X = cell.camera.T_flange_optical
    rig = LandmarkRig(DirectCamera(SimCamera(sim, arm), arm), cell, model.chain(tool=X),
                      model.chain(tool=X))
    return PortRobot(DirectRobot(arm, sim.probe), model.chain(tool=cell.T_flange_tool),
                     cell.home, CAPTURE_DURATION, rig)


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
    # F_i put every reading near the middle of the 0.2-2.2 mm range, stored for the report
    assert np.all(np.abs(trial.distances - 1.2e-3) < 0.2e-3)
    assert trial.meta['probe_range_m'] == pytest.approx([0.2e-3, 2.2e-3])


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
    assert stopped.value.code == ErrorCode.CANCELED
    half = store.load('t1')
    assert half.meta['status'] == 'aborted' and half.resume == (1, 2)
    done = TrialRun(_plan('rigid', 3, trial_id='t1'), robot(6), store).resume(half)
    assert done.meta['status'] == 'done' and done.resume is None
    np.testing.assert_array_equal(done.distances[:, 0], half.distances[:, 0])
    assert np.all(np.isfinite(done.distances))


@pytest.mark.parametrize('short_m, steps', [(1.5e-3, 1), (2.5e-3, 2)])
def test_an_out_of_range_reading_is_corrected_by_ff(tmp_path, short_m, steps):
    """At one visit the robot lands ``short_m`` short, out of range: eq (15) moves 1 mm closer
    (again, up to MAX_FF_STEPS times, when still out of range), reads, and refers the reading
    back to the commanded point with the total FF. 2.5 mm: a single-landmark frame on the wide
    layout is off by that much."""
    arm = robot(8)
    store = TrialStore(tmp_path)
    run = TrialRun(_plan('reference', 2, trial_id='ff'), arm, store)
    original_read, state = arm.read, {'n': 0}
    faked = range(8, 8 + steps + 1)   # after the 5 set-up readings: cycle 1, P3 and retries

    def read_short_at_one_visit():
        state['n'] += 1
        reading = original_read()
        if state['n'] not in faked:
            return reading
        back = retreat(arm.port.sim.true_tool(), 5e-3)      # the gap as if the marker were lower
        gap = SIM.world.probe_gap(back) - 5e-3 + short_m
        return (Reading(math.nan, ReadingStatus.ABOVE_RANGE) if gap > SIM.probe.max_range
                else Reading(gap, ReadingStatus.OK))
    arm.read = read_short_at_one_visit
    trial = run.start()
    rows = (tmp_path / 'trials' / 'ff' / 'distances.csv').read_text().splitlines()
    corrected = [r.split(',') for r in rows[1:] if 'closer' in r]
    assert len(corrected) == 1 and corrected[0][2] == 'P3'
    raw, ff = float(corrected[0][3]), float(corrected[0][4])
    assert ff == pytest.approx(steps * 1.0e-3)
    assert raw == pytest.approx(1.2e-3 - steps * 1.0e-3 + short_m, abs=2e-4)
    assert trial.distances[2, 0] == pytest.approx(raw + ff)    # 1.2 mm + the short landing


def test_a_trial_resumed_mid_cycle_measures_that_cycle_again_through_one_frame(
        tmp_path, monkeypatch):
    """Stopped after P1, P2 of cycle 2: the resumed run fits cycle 2's frame M_n once and
    measures all of P1..P5 through it; the first attempt's P1, P2 are superseded."""
    store, events = TrialStore(tmp_path), []
    fit = user_frame.calibrate
    monkeypatch.setattr(user_frame, 'calibrate',
                        lambda *a, **k: events.append('fit') or fit(*a, **k))
    run = TrialRun(_plan('rigid', 3, trial_id='mid'), robot(5), store,
                   on_reading=lambda c, i, d: events.append((c, i)),
                   stop_requested=lambda: len(events) >= 9)   # fit, 5 readings, fit, 2
    with pytest.raises(TrialError, match='resume'):
        run.start()
    half = store.load('mid')
    assert half.resume == (1, 2) and np.isfinite(half.distances[:2, 1]).all()
    events.clear()
    done = TrialRun(_plan('rigid', 3, trial_id='mid'), robot(6), store,
                    on_reading=lambda c, i, d: events.append((c, i))).resume(half)
    m = len(CELL.markers)
    assert events == ['fit', *[(1, i) for i in range(m)], 'fit', *[(2, i) for i in range(m)]]
    assert done.meta['status'] == 'done' and np.all(np.isfinite(done.distances))
    assert not np.any(done.distances[:2, 1] == half.distances[:2, 1])   # measured again
    np.testing.assert_array_equal(done.distances[:, 0], half.distances[:, 0])


def test_a_trial_that_fails_midway_is_stored_as_aborted_and_resumes(tmp_path):
    """A lost probe is no longer a running trial (the latest status change, for the topic)."""
    arm, store = robot(4), TrialStore(tmp_path)
    read, count = arm.read, []

    def read_then_lose_the_probe():
        count.append(1)
        if len(count) == 12:
            raise TrialError(ErrorCode.PROBE_FAILED, 'probe/average: no answer within 5 s')
        return read()
    arm.read = read_then_lose_the_probe
    with pytest.raises(TrialError, match='no answer'):
        TrialRun(_plan('reference', 3, trial_id='lost'), arm, store).start()
    half = store.load('lost')
    assert half.meta['status'] == 'aborted' and half.resume is not None
    done = TrialRun(_plan('reference', 3, trial_id='lost'), robot(5), store).resume(half)
    assert done.meta['status'] == 'done' and np.all(np.isfinite(done.distances))


def test_a_reference_trial_also_resumes_at_the_start_of_its_cycle(tmp_path):
    """The ISO cycle visits P1..Pm in order: a resumed cycle starts again at P1."""
    store, readings = TrialStore(tmp_path), []
    run = TrialRun(_plan('reference', 2, trial_id='ref'), robot(2), store,
                   on_reading=lambda c, i, d: readings.append((c, i)),
                   stop_requested=lambda: len(readings) >= 8)
    with pytest.raises(TrialError):
        run.start()
    readings.clear()
    TrialRun(_plan('reference', 2, trial_id='ref'), robot(3), store,
             on_reading=lambda c, i, d: readings.append((c, i))).resume(store.load('ref'))
    assert readings == [(1, i) for i in range(len(CELL.markers))]


@pytest.mark.parametrize('method, axis, cycles, message', [
    ('four_point', 'z', 2, 'unknown method'), ('rigid', 'w', 2, 'unknown axis'),
    ('', 'z', 2, 'unknown method'), ('rigid', '', 2, 'unknown axis'),
    ('reference', 'z', 1, 'cycles must be 2..10000'),
    ('reference', 'z', 10001, 'cycles must be 2..10000')])
def test_bad_plans_are_refused_before_moving(tmp_path, method, axis, cycles, message):
    arm = robot(1)
    with pytest.raises(TrialError, match=message):
        TrialRun(_plan(method, cycles, axis, trial_id='bad'), arm, TrialStore(tmp_path))
    assert arm.port.moves == 0


@pytest.mark.parametrize('method, axis, cycles, message', [
    ('four_point', '', 0, "unknown method 'four_point'; use one of reference, three_point"),
    ('landmark_icp', '', 0, 'unknown method'),
    ('', 'w', 0, "unknown axis 'w'; use one of x, y, z"),
    ('', '', 1, 'cycles must be 2..10000'), ('', '', 10001, 'cycles must be 2..10000'),
    ('', '', -1, 'got -1')])
def test_goal_problem_names_what_is_wrong(method, axis, cycles, message):
    problem = goal_problem(method, axis, cycles)
    assert problem.code == ErrorCode.INVALID_INPUT and message in problem.message


@pytest.mark.parametrize('method, axis, cycles', [
    ('', '', 0), ('robust', 'x', 2), ('reference', 'z', 10000)])
def test_goal_problem_accepts_defaults_and_every_method_and_axis(method, axis, cycles):
    assert goal_problem(method, axis, cycles) is None
    assert all(goal_problem(m, a, 0) is None for m in METHODS for a in AXES)


STORED = {'id': 't7', 'method': 'rigid', 'axis': 'x', 'cycles_total': 3}


@pytest.mark.parametrize('method, axis, cycles', [
    ('', '', 0), ('rigid', '', 0), ('', 'x', 3), ('rigid', 'x', 3)])
def test_a_resume_may_leave_out_or_repeat_the_stored_settings(method, axis, cycles):
    assert resume_problem(STORED, method, axis, cycles) is None


@pytest.mark.parametrize('method, axis, cycles, differ', [
    ('reference', '', 0, 'method reference (stored: rigid)'),
    ('', 'z', 0, 'axis z (stored: x)'),
    ('', '', 30, 'cycles 30 (stored: 3)'),
    ('reference', 'x', 30, 'method reference (stored: rigid), cycles 30 (stored: 3)')])
def test_a_resume_with_other_settings_is_refused_saying_what_is_stored(method, axis, cycles,
                                                                       differ):
    problem = resume_problem(STORED, method, axis, cycles)
    assert problem.code == ErrorCode.INVALID_INPUT
    problem = problem.message
    assert problem.startswith('trial t7 is rigid, x axis, 3 cycles; cannot resume it with ')
    assert differ in problem and 'leave those out' in problem


def test_landmark_methods_on_the_wide_layout_rank_as_issue_11_asks(tmp_path):
    """Issue 11, must-show 3, in-process (the ROS path differs only in how views are taken):
    on the wide set-up with the non-planar table, landmark_multi repeats at least 5x better
    than landmark_single (one marker's plane) and within 1.5x of five_point_lsq. Camera poses
    come from the nominal hand-eye, as before a hand-eye calibration. The paper's close-layout
    figures: RPS 1.42 mm (z), five points 0.12 mm."""
    from cobot_calib_ros.core.repeatability import point_statistics
    from cobot_calib_ros.core.repeatability.trial import mean_calibration_seconds
    wide = load_simulation(cell_file('sawyer_close'), 'wide')
    rp, seconds = {}, {}
    for method in ('five_point_lsq', 'landmark_single', 'landmark_multi'):
        plan = _plan(method, 30, trial_id=method, cell=wide.cell)
        trial = TrialRun(plan, robot(3, wide), TrialStore(tmp_path / method)).start()
        rp[method] = point_statistics(trial.distances).rp_all
        seconds[method] = mean_calibration_seconds(trial.meta)
        assert sum(t is not None for t in trial.meta['calibration_s']) == 30
    print({m: f'RP_all {v * 1e3:.3f} mm, calibration {seconds[m]:.1f} s'
           for m, v in rp.items()})
    assert rp['landmark_single'] >= 5 * rp['landmark_multi'], rp
    assert rp['landmark_multi'] <= 1.5 * rp['five_point_lsq'], rp
    assert 0.5e-3 < rp['landmark_single'] < 3e-3      # the paper's RPS class, not a broken fit
    # 18 views against one; five probed points against one view
    assert seconds['landmark_multi'] > 5 * seconds['landmark_single'] > 0


def test_a_probe_signal_that_is_not_a_number_stops_the_trial_as_on_the_nodes(tmp_path):
    """proximity_sensor's rule, now also in-process (core.sensors.probe.average): a window of
    INVALID readings is no reading, a probe failure; the in-process robot used to call it
    ABOVE_RANGE and let the set-up step the probe away from the marker."""
    arm = robot(2)
    arm.port.sim.probe_voltage = lambda: math.nan
    with pytest.raises(TrialError, match='INVALID') as stopped:
        TrialRun(_plan('reference', 2, trial_id='nan'), arm, TrialStore(tmp_path)).start()
    assert stopped.value.code == ErrorCode.PROBE_FAILED
    assert arm.port.moves == 5 + 2          # the five touches, then one approach and arrival
