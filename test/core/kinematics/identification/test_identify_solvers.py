"""identify(): Nelder-Mead against LM, robust loss, callback and cancellation, input errors."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification import (
    absolute_errors, all_pairs, identify, ParameterSet, PositionObservations,
    SphereObservations, tool_frames, uniform_configurations)
from cobot_calib_ros.core.kinematics.identification.solvers import NM_CONVERGED
from sphere_scene import MODEL, sphere_data, TOOL, true_robot

FREE = ('d_3', 'd_5', 'alpha_4', 'tool_x')
CORNERS = (-20.0, 20.0)


@pytest.fixture(scope='module')
def truth():
    return true_robot(FREE, seed=3)


@pytest.fixture(scope='module')
def data(truth) -> SphereObservations:
    """16 poses per sphere (rx, ry, rz, arm at +-20 deg), 48 rows."""
    return sphere_data(*truth, CORNERS, CORNERS)


def free_values(result) -> np.ndarray:
    return ParameterSet(MODEL, FREE).values(result.params, result.tool_xyz)


def recorder(stop_at: int | None = None):
    calls = []

    def callback(iteration: int, cost: float, rms_m: float) -> bool:
        calls.append((iteration, cost, rms_m))
        return stop_at is None or iteration < stop_at
    return calls, callback


def test_nelder_mead_converges_to_the_lm_minimum(truth, data):
    """Paper's solver on its eq 11 (pairs form, 1128 pairs), from nominal, 4 unknowns."""
    ps = ParameterSet(MODEL, FREE)
    pairs = all_pairs(np.arange(len(data.q)))
    calls, callback = recorder()
    nm = identify(ps, data, tool_xyz0=TOOL, solver='nelder-mead', loss='linear', pairs=pairs,
                  callback=callback, max_iterations=4000)
    lm = identify(ps, data, tool_xyz0=TOOL, loss='linear', pairs=pairs)
    print(f'NM: {nm.iterations} iterations, {nm.solve_seconds:.2f} s, cost {calls[0][1]:.3g} '
          f'-> {nm.cost:.3g}; LM: {lm.iterations} iterations, cost {lm.cost:.3g}')
    assert nm.code == ErrorCode.SUCCESS and 'terminated successfully' in nm.message
    assert [c[0] for c in calls] == list(range(len(calls)))
    assert calls[-1][0] == nm.iterations
    assert nm.cost < 1e-8 * calls[0][1]
    assert all(b[1] <= a[1] for a, b in zip(calls, calls[1:]))  # best cost never rises
    assert free_values(nm) == pytest.approx(ParameterSet(MODEL, FREE).values(*truth),
                                            abs=1e-8)
    assert free_values(nm) == pytest.approx(free_values(lm), abs=1e-8)


def test_scipy_default_tolerances_stop_nelder_mead_early(data):
    """Why the tolerances are exposed: scipy's xatol = fatol = 1e-4 stop far from the
    minimum on this problem (1e-4 of a 1 mm step is 0.1 um, fatol 1e-4 m^2 is huge)."""
    pairs = all_pairs(np.arange(len(data.q)))
    ps = ParameterSet(MODEL, FREE)
    early = identify(ps, data, tool_xyz0=TOOL, solver='nelder-mead', loss='linear',
                     pairs=pairs, xatol=1e-4, fatol=1e-4)
    tight = identify(ps, data, tool_xyz0=TOOL, solver='nelder-mead', loss='linear',
                     pairs=pairs)
    assert early.iterations < tight.iterations
    assert early.cost > 1e3 * tight.cost


@pytest.mark.parametrize(('solver', 'stop_at'), [('lm', 1), ('nelder-mead', 3)])
def test_callback_cancels(data, solver, stop_at):
    """(LM converges in 3 iterations here: stopped after its first.)"""
    calls, callback = recorder(stop_at)
    result = identify(ParameterSet(MODEL, FREE), data, tool_xyz0=TOOL, solver=solver,
                      loss='linear', callback=callback)
    assert result.code == ErrorCode.CANCELED and 'cancelled' in result.message
    assert [c[0] for c in calls] == list(range(stop_at + 1)) and result.iterations == stop_at
    assert np.all(np.isfinite(result.params)) and np.all(np.isfinite(result.tool_xyz))
    assert result.cost == pytest.approx(calls[-1][1], rel=1e-12)
    # the best point so far: LM improves at every iteration, Nelder-Mead may keep its start
    assert result.cost < calls[0][1] if solver == 'lm' else result.cost <= calls[0][1]
    finished = identify(ParameterSet(MODEL, FREE), data, tool_xyz0=TOOL, solver=solver,
                        loss='linear', max_iterations=50)
    assert finished.cost < result.cost


def test_callback_returning_none_does_not_cancel(data):
    result = identify(ParameterSet(MODEL, FREE), data, tool_xyz0=TOOL, loss='linear',
                      callback=lambda *args: None)
    assert result.code == ErrorCode.SUCCESS and result.rms_m < 1e-9


def test_a_robust_loss_ends_at_its_own_minimum_from_the_least_squares_start(truth, data):
    """identify() runs a robust loss from the least-squares solution (issue 28.8: from the
    nominal start soft-L1 crawled through its L1 tail): the same minimum of the robust cost as
    scipy run from the nominal start, with an outlier that moves the least-squares one; the
    callback counts the iterations of both stages once each."""
    from scipy.optimize import least_squares
    from cobot_calib_ros.core.kinematics.identification.objectives import CentresObjective
    q = data.q.copy()
    q[5, 0] += 0.01
    bad = SphereObservations(q, data.sphere, data.known_distances)
    ps = ParameterSet(MODEL, FREE)
    calls, callback = recorder()
    robust = identify(ps, bad, tool_xyz0=TOOL, loss='soft_l1', f_scale=1e-5, callback=callback)
    linear = identify(ps, bad, tool_xyz0=TOOL, loss='linear')
    problem = CentresObjective(ps, bad, MODEL.nominal, TOOL)
    direct = least_squares(problem.residuals, problem.x0, jac=problem.jacobian, method='trf',
                           loss='soft_l1', f_scale=1e-5, x_scale='jac', ftol=1e-12,
                           xtol=1e-12, gtol=1e-12)
    assert robust.converged
    assert np.abs(free_values(robust) - free_values(linear)).max() > 1e-5   # the outlier
    assert free_values(robust) == pytest.approx(direct.x[:len(FREE)], abs=1e-10)
    assert robust.cost == pytest.approx(direct.cost, rel=1e-9)
    assert [c[0] for c in calls] == list(range(robust.iterations + 1))


def test_soft_l1_resists_an_outlier(truth, data):
    """One coupling recorded 0.01 rad off on joint 1 (~6 mm at the tool): the robust loss
    keeps the held-out error near 0, least squares does not."""
    q = data.q.copy()
    q[5, 0] += 0.01
    bad = SphereObservations(q, data.sphere, data.known_distances)
    ps = ParameterSet(MODEL, FREE)
    held_out = uniform_configurations(MODEL, 100, 1)
    p_true = tool_frames(MODEL, *truth, held_out)[:, :3, 3]
    worst = {}
    for loss in ('linear', 'soft_l1'):
        r = identify(ps, bad, tool_xyz0=TOOL, loss=loss, f_scale=1e-5)
        worst[loss] = absolute_errors(MODEL, r.params, r.tool_xyz, held_out, p_true).max()
    print({k: f'{v * 1e3:.4f} mm' for k, v in worst.items()})
    assert worst['linear'] > 0.1e-3
    assert worst['soft_l1'] < 0.1 * worst['linear']


def test_fewer_poses_than_free_parameters_are_enough_when_the_residuals_outnumber_the_unknowns(
        data):
    """Three poses on one sphere: 9 residuals for the 4 parameters and the centre (7). A
    rule of one pose per free parameter refused this (and a planned collection that stopped
    at 20 poses of a 24-parameter Sawyer, 60 residuals for 36 unknowns)."""
    few = SphereObservations(data.q[:3], np.array([0, 0, 0]))
    result = identify(ParameterSet(MODEL, FREE), few, tool_xyz0=TOOL, loss='linear')
    assert result.params.shape == MODEL.nominal.shape and np.isfinite(result.params).all()


def test_bad_input_raises_with_advice(data):
    ps = ParameterSet(MODEL, FREE)
    q = data.q.copy()
    q[3, 2] = np.nan
    with pytest.raises(ValueError, match=r'NaN or inf in rows \[3\]'):
        SphereObservations(q, data.sphere, data.known_distances)
    with pytest.raises(ValueError, match=r'spheres \[9\] have fewer than 2 rows'):
        SphereObservations(data.q[:5], np.array([0, 0, 1, 1, 9]))
    with pytest.raises(ValueError, match='two different spheres'):
        SphereObservations(data.q[:4], np.array([0, 0, 1, 1]), ((0, 2, 0.3),))
    with pytest.raises(ValueError, match='integer'):
        SphereObservations(data.q[:4], np.array([0.0, 0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match='unknown parameter names'):
        ParameterSet(MODEL, ('d_3', 'link_length'))
    with pytest.raises(ValueError, match='repeated'):
        ParameterSet(MODEL, ('d_3', 'd_3'))
    few = SphereObservations(data.q[:2], np.array([0, 0]))
    # 2 poses on one sphere: 6 residuals for 4 parameters and the sphere's centre
    with pytest.raises(ValueError, match='6 residuals for 7 unknowns: record more poses'):
        identify(ps, few, tool_xyz0=TOOL)
    with pytest.raises(ValueError, match='needs PositionObservations'):
        identify(ps, data, tool_xyz0=TOOL, objective='absolute')
    with pytest.raises(ValueError, match='no usable pair'):
        unknown = SphereObservations(data.q, data.sphere)
        identify(ps, unknown, tool_xyz0=TOOL, pairs=np.array([[0, len(data.q) - 1]]))
    with pytest.raises(ValueError, match='two different rows'):
        identify(ps, data, tool_xyz0=TOOL, pairs=np.array([[0, 0]]))
    with pytest.raises(ValueError, match='solver must be'):
        identify(ps, data, tool_xyz0=TOOL, solver='bfgs')
    with pytest.raises(ValueError, match='loss must be'):
        identify(ps, data, tool_xyz0=TOOL, loss='l2')
    with pytest.raises(ValueError, match='tool_xyz0 must be 3 finite'):
        identify(ps, data, tool_xyz0=[0.0, np.nan, 0.1])
    with pytest.raises(ValueError, match="q has 6 joints, model 'iiwa7' has 7"):
        identify(ps, SphereObservations(data.q[:, :6], data.sphere), tool_xyz0=TOOL)
    with pytest.raises(ValueError, match='3 residuals for 4 unknowns: record more poses'):
        identify(ps, data, tool_xyz0=TOOL, pairs=np.array([[0, 1]]))
    with pytest.raises(ValueError, match='at least 3 rows'):
        two = PositionObservations(data.q[:2], np.zeros((2, 3)))
        identify(ParameterSet(MODEL, ('d_3',)), two, tool_xyz0=TOOL)
    p = np.zeros((4, 3))
    p[1, 0] = np.inf
    with pytest.raises(ValueError, match=r'p has NaN or inf in rows \[1\]'):
        PositionObservations(data.q[:4], p)
    tracker = PositionObservations(data.q[:4], np.zeros((4, 3)))
    with pytest.raises(ValueError, match='pairs apply to the relative'):
        identify(ps, tracker, tool_xyz0=TOOL, pairs=np.array([[0, 1]]))


@pytest.mark.parametrize(('solver', 'cap', 'why'), [
    ('nelder-mead', {'max_evaluations': 40}, 'Maximum number of function evaluations'),
    ('lm', {'max_iterations': 2}, 'number of function evaluations')])
def test_a_solver_stopped_by_its_cap_says_it_did_not_converge(truth, data, solver, cap, why):
    """Issue 16.6: Nelder-Mead with scipy's caps stopped early and said nothing."""
    ps = ParameterSet(MODEL, FREE)
    pairs = all_pairs(np.arange(len(data.q)))
    capped = identify(ps, data, tool_xyz0=TOOL, solver=solver, loss='linear', pairs=pairs,
                      **cap)
    assert not capped.converged and capped.code == ErrorCode.SUCCESS
    assert capped.message.startswith('did not converge: ') and why in capped.message
    options = NM_CONVERGED if solver == 'nelder-mead' else {}
    full = identify(ps, data, tool_xyz0=TOOL, solver=solver, loss='linear', pairs=pairs,
                    **options)
    assert full.converged and not full.message.startswith('did not converge')
    assert free_values(full) == pytest.approx(ParameterSet(MODEL, FREE).values(*truth),
                                              abs=1e-8)
    assert capped.cost > 1e3 * full.cost
