"""One identification engine (issue 28 item 5, must-show 2): live sphere data, as the node's
CalibrationJob takes them, and the same data written as a measurement file (CSV and sidecar,
as the README describes the spheres kind) and identified by `identify --measurement`'s
api.identification.identify_source, go through the same core call
(measurement_fit.calibrate) with the same measurements and come out with the same parameters
and the same gate verdict; the gates refuse both the same way."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.api.identification import identify_source
from cobot_calib_ros.core.errors import Refusal
from cobot_calib_ros.core.kinematics import model_for, plans
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds
from cobot_calib_ros.core.kinematics.identification.observations import SphereObservations
from cobot_calib_ros.core.kinematics.kinematic_calibration import CalibrationJob, JobCancelled
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

POSES = 90


@pytest.fixture(scope='module')
def live():
    """Sphere observations of the mock UR10e (config/cells/ur10e_close.yaml) as a collection
    records them: the coupling pulled onto the true spheres, the joints averaged readings."""
    sim = load_simulation(cell_file('ur10e_close'))
    robot, model = SimRobot(sim), model_for(sim.cell)
    steps, skipped = plans.sphere_plan(sim.cell, model, POSES)
    assert not skipped
    q = []
    for step in steps:
        robot.set_joints(robot.plan_compliant(np.array(step['q'])))
        q.append(np.mean([robot.joint_reading() for _ in range(20)], axis=0))
    data = SphereObservations(np.array(q), np.array([s['target'] for s in steps]),
                              sim.cell.spheres.known_distances())
    return sim, model, data


def write_measurement_file(folder, sim, model, data: SphereObservations,
                           length_scale: float = 1.0):
    """NAME.csv + NAME.yaml of the spheres kind, full precision (repr), and the cell's URDF;
    ``length_scale`` multiplies the sidecar's lengths (1000: millimetres left declared as
    metres)."""
    csv = folder / 'spheres.csv'
    lines = [','.join(model.joint_names + ('sphere',))]
    lines += [','.join([repr(float(v)) for v in row] + [str(int(s))])
              for row, s in zip(data.q, data.sphere)]
    csv.write_text('\n'.join(lines) + '\n')
    ball = sim.cell.spheres.T_flange_coupling[:3, 3] * length_scale
    distances = [[i, j, repr(d * length_scale)] for i, j, d in data.known_distances]
    robot = sim.cell.urdf_robot
    (folder / 'spheres.yaml').write_text(
        'measurement: spheres\n'
        'units: {length: m, angle: rad}\n'
        f'joints: [{", ".join(model.joint_names)}]\n'
        f'frames: {{base: {robot.base_link}, tip: {robot.tip_link}}}\n'
        'sphere: sphere\n'
        f'distances: [{", ".join(f"[{i}, {j}, {d}]" for i, j, d in distances)}]\n'
        f'ball: [{", ".join(repr(float(v)) for v in ball)}]\n')
    urdf = folder / 'robot.urdf'
    urdf.write_text(robot.urdf)
    return csv, str(urdf)


@pytest.fixture
def spy(monkeypatch):
    """Every measurement_fit.calibrate call: (measurements, its Calibration)."""
    calls = []
    real = mf.calibrate

    def calibrate(errors, data, **kwargs):
        out = real(errors, data, **kwargs)
        calls.append((errors, data, kwargs, out))
        return out
    monkeypatch.setattr(mf, 'calibrate', calibrate)
    return calls


def same_measurements(a, b) -> None:
    assert (a.kind, a.distances) == (b.kind, b.distances)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.target, b.target)
    np.testing.assert_array_equal(a.ball, b.ball)


def test_live_sphere_data_and_their_measurement_file_identify_the_same(live, tmp_path, spy):
    sim, model, data = live
    csv, urdf = write_measurement_file(tmp_path, sim, model, data)
    outcome = CalibrationJob(sim.cell, model, data).run()
    report = identify_source(csv, measurement='spheres', urdf=urdf, folds=3)
    # the same core call with the same measurements, error model and options
    (e_live, m_live, k_live, c_live), (e_file, m_file, k_file, c_file) = spy
    assert (e_live.name, e_file.name) == ('full', 'full')
    assert e_live.model.parameter_names == e_file.model.parameter_names
    np.testing.assert_array_equal(e_live.model.nominal, e_file.model.nominal)
    same_measurements(m_live, m_file)
    assert {k: k_live[k] for k in ('loss', 'bounds')} == {k: k_file[k] for k in ('loss', 'bounds')}
    # the same identified parameters (the live result adds the ball as tool_x, tool_y, tool_z)
    file_values = {p['name']: p['value'] for p in report['identified']}
    live_values = dict(zip(outcome.result.free, outcome.free_values))
    assert list(outcome.result.free[-3:]) == ['tool_x', 'tool_y', 'tool_z']
    assert list(file_values) == list(outcome.result.free[:-3]) and len(file_values) >= 15
    for name, value in file_values.items():
        assert live_values[name] == pytest.approx(value, rel=1e-9, abs=1e-12), name
    assert outcome.result.p_flange_tool == pytest.approx(c_file.fit.nuisance[:3], rel=1e-9,
                                                    abs=1e-12)
    assert [d.name for d in outcome.identifiability.dropped] == \
        [d['name'] for d in report['dropped']]
    # and it is a calibration: the fit moved the parameters well beyond that agreement
    deltas = np.abs([p['delta'] for p in report['identified']])
    assert deltas.max() > 1e-4
    # the same gate verdict: the fit's own problems (none) and a pass on both paths
    assert c_live.problems == c_file.problems == ()
    assert outcome.verdict.passed and report['verdict']['passed']
    assert outcome.result.converged and report['converged']


def test_the_gates_refuse_live_data_and_their_file_the_same_way(live, tmp_path):
    """Millimetres left declared as metres (the known distances and the ball): the same one
    line before any fit on both paths."""
    sim, model, data = live
    csv, urdf = write_measurement_file(tmp_path, sim, model, data, length_scale=1000.0)
    mm = SphereObservations(data.q, data.sphere,
                            tuple((i, j, d * 1000.0) for i, j, d in data.known_distances))
    with pytest.raises(Refusal) as live_refusal:
        CalibrationJob(sim.cell, model, mm,
                       p_flange_tool0=sim.cell.spheres.T_flange_coupling[:3, 3] * 1000.0).run()
    with pytest.raises(Refusal) as file_refusal:
        identify_source(csv, measurement='spheres', urdf=urdf, folds=3)
    assert str(live_refusal.value) == str(file_refusal.value)
    assert str(live_refusal.value).startswith('REFUSED: ')
    assert 'millimetres declared as metres' in str(live_refusal.value)


def test_a_deviation_on_its_bound_is_refused_the_same_way(live, tmp_path):
    """Bounds tighter than the arm's errors: both results carry the same problems, the
    parameters that ran to their bounds."""
    sim, model, data = live
    csv, urdf = write_measurement_file(tmp_path, sim, model, data)
    tight = DeviationBounds(2e-5, 2e-5)
    outcome = CalibrationJob(sim.cell, model, data, bounds=tight).run()
    report = identify_source(csv, measurement='spheres', urdf=urdf, folds=3,
                             max_deviation=(tight.length_m, tight.angle_rad))
    at_bound = [p for p in outcome.verdict.problems if 'ran to its bound' in p]
    assert at_bound and not outcome.verdict.passed
    assert at_bound == [p for p in report['verdict']['problems'] if 'ran to its bound' in p]


@pytest.mark.parametrize('solver', ['lm', 'nelder-mead'])
def test_the_solve_reports_progress_and_stops_when_the_callback_says(live, solver):
    """The node's feedback and cancel: the callback sees the start (iteration 0) and every
    iteration with the cost so far; returning False stops the solve (JobCancelled)."""
    sim, model, data = live
    seen = []

    def stop_after_two(iteration: int, cost: float, rms: float) -> bool:
        seen.append((iteration, cost, rms))
        return iteration < 2
    with pytest.raises(JobCancelled, match='cancelled by the callback at iteration 2'):
        CalibrationJob(sim.cell, model, data, solver=solver).run(stop_after_two)
    assert [s[0] for s in seen] == [0, 1, 2]
    assert seen[2][1] <= seen[1][1] <= seen[0][1] and seen[0][2] > 0.0
    if solver == 'lm':
        iterations = []
        outcome = CalibrationJob(sim.cell, model, data).run(
            lambda i, cost, rms: iterations.append(i) is None)
        assert iterations == list(range(outcome.result.iterations + 1))


def test_a_recorded_session_takes_the_same_call(spy):
    """`identify --source BAG` (api.identification.identify_source): the bag's captures as
    spheres measurements through measurement_fit.calibrate, its problems the report's."""
    from pathlib import Path
    bag = Path(__file__).resolve().parents[2] / 'bags' / 'iiwa_spheres'
    report = identify_source(bag, cell='iiwa7_close')
    (_, measurements, _, calibration), = spy
    assert measurements.kind == 'spheres' and len(measurements) == report['rows'] == 150
    assert list(calibration.fit.names + ('tool_x', 'tool_y', 'tool_z')) == \
        [p['name'] for p in report['identified']]
    assert report['verdict']['problems'] == list(calibration.problems) == []
