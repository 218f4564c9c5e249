"""The measurement Jacobian through the tip's twists (tip_jacobian, issue 28.8) against central
differences of the residuals over every unknown, the way measurement_fit computed it before:
every kind of measurement, the three error models, a prismatic joint."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.measurements import Measurements
from cobot_calib_ros.core.kinematics.model import dh_model, fk, parameter_twists
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
from test_measurement_fit import configurations, mock, UR10E

STEP = 1e-6


@pytest.fixture(scope='module')
def ur10e():
    return model_from_urdf(UR10E.read_text(), 'base_link', 'wrist_3_link', 'ur10e')


def lift():
    """The UR10e on a prismatic lift, its axis tilted (as test_measurement_fit's)."""
    text = UR10E.read_text().replace(
        '<joint name="base_link-base_link_inertia" type="fixed">',
        '<joint name="base_link-base_link_inertia" type="prismatic"><axis xyz="0.05 0 1"/>'
        '<limit lower="0" upper="0.4" effort="0" velocity="0"/>', 1)
    return model_from_urdf(text, 'base_link', 'wrist_3_link', 'ur10e_lift')


def arm():
    dh = [[0.16, 0.0, 0.0, 1.57], [0.0, -0.3, -0.42, 0.0], [0.0, 0.2, -0.39, 0.0],
          [0.13, 0.0, 0.0, 1.57], [0.1, 0.1, 0.0, -1.57], [0.1, 0.0, 0.0, 0.0]]
    return dh_model('arm6', tuple(f'j{i}' for i in range(6)), dh, [(-3.0, 3.0)] * 6)


def synthetic(kind: str, q: np.ndarray) -> Measurements:
    """Measurements the residuals need not fit: the Jacobian holds everywhere."""
    target = np.arange(len(q)) % 3
    if kind == 'spheres':
        return Measurements('spheres', q, target, distances=((0, 1, 0.3), (1, 2, 0.25)),
                            ball=[0.01, -0.02, 0.1])
    return Measurements('plane', q, target, ball=[0.02, 0.01, 0.12])


def central_differences(problem, x: np.ndarray) -> np.ndarray:
    columns = []
    for k in range(len(x)):
        step = np.zeros(len(x))
        step[k] = STEP
        columns.append((problem.residuals(x + step) - problem.residuals(x - step)) / (2 * STEP))
    return np.stack(columns, axis=1)


def cases(ur10e):
    q7 = np.hstack([np.random.default_rng(8).uniform(0.0, 0.4, (30, 1)),
                    configurations(ur10e, 30)])
    yield 'pose, full', ur10e, 'full', mock('pose', ur10e)
    yield 'points, full', ur10e, 'full', mock('points', ur10e)
    yield 'points, offsets', ur10e, 'offsets', mock('points', ur10e)
    yield 'spheres, full', ur10e, 'full', synthetic('spheres', configurations(ur10e, 30))
    yield 'plane, offsets', ur10e, 'offsets', synthetic('plane', configurations(ur10e, 30))
    yield 'spheres, mdh', arm(), 'mdh', synthetic('spheres', configurations(arm(), 30))
    yield 'plane, full, prismatic lift', lift(), 'full', synthetic('plane', q7)
    yield 'spheres, offsets, prismatic lift', lift(), 'offsets', synthetic('spheres', q7)


def test_the_jacobian_through_the_tip_twists_is_the_residuals_derivative(ur10e):
    rng = np.random.default_rng(2)
    for name, model, error_model, data in cases(ur10e):
        errors = mf.ErrorModel(model, error_model)
        problem = mf._Problem(errors, data, errors.candidates)
        x = problem.x0 + rng.normal(0.0, 1e-3, problem.x0.shape)   # off the nominal model
        J, reference = problem.jacobian(x), central_differences(problem, x)
        scale = np.linalg.norm(reference, axis=0)
        assert np.all(scale[:problem.n] > 0.0), name
        error = np.abs(J - reference).max(axis=0) / np.where(scale > 0.0, scale, 1.0)
        print(f'{name}: {J.shape}, worst {error.max():.1e} of a column')
        assert error.max() < 1e-6, name


def test_parameter_twists_move_the_tip_as_the_parameters_and_joints_do(ur10e):
    """dT/dh = [w]x R, v + w x p for every parameter and joint (central differences of FK)."""
    for model in (ur10e, arm(), lift()):
        params = model.nominal + np.random.default_rng(1).normal(0.0, 1e-3, model.nominal.shape)
        q = configurations(model, 5) if model.name != 'ur10e_lift' else np.hstack(
            [[[0.1], [0.3], [0.2], [0.0], [0.4]], configurations(ur10e, 5)])
        twists, joints = parameter_twists(model, params, q)
        T = fk(model.chain(params), q)

        def moved(dparams, dq):
            return (fk(model.chain(params + dparams), q + dq)
                    - fk(model.chain(params - dparams), q - dq)) / (2 * STEP)

        unit = np.eye(len(params)) * STEP
        unit_q = np.eye(q.shape[1]) * STEP
        derivatives = [(twists[k], moved(unit[k], 0.0)) for k in range(len(params))] + [
            (joints[i], moved(0.0, unit_q[i])) for i in range(q.shape[1])]
        for xi, dT in derivatives:
            v, w = xi[:, :3], xi[:, 3:]
            np.testing.assert_allclose(dT[:, :3, 3], v + np.cross(w, T[:, :3, 3]), atol=1e-8)
            np.testing.assert_allclose(dT[:, :3, :3], np.cross(w[:, :, None], T[:, :3, :3],
                                                               axis=1), atol=1e-8)
