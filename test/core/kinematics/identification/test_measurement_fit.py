"""Identification from the four kinds of measurement (measurement_fit): noise-free mock data of a
UR10e whose joint origins are off recover the truth on held-out rows; identifiability, folds,
the outlier rule and refusals."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.core.frames import from_vector
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.measurements import Measurements
from cobot_calib_ros.core.kinematics.model import dh_model, fk
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf

DATA = Path(__file__).resolve().parents[3] / 'data'
UR10E = DATA / 'figaroh-ur10e' / 'robot.urdf'


@pytest.fixture(scope='module')
def ur10e():
    return model_from_urdf(UR10E.read_text(), 'base_link', 'wrist_3_link', 'ur10e')


def truth(model, seed=3):
    """Joint origins off by ~1 mm / 1 mrad (every parameter)."""
    rng = np.random.default_rng(seed)
    return model.nominal + rng.normal(0.0, 1e-3, model.nominal.shape)


def configurations(model, m, seed=4):
    rng = np.random.default_rng(seed)
    return rng.uniform(-2.5, 2.5, (m, len(model.joint_names)))


def tip_true(model, params, q):
    return fk(model.chain(params), q)


BASE = from_vector([1.2, -0.3, 0.5, 0.2, -0.1, 2.0])      # T_world_base of the mock cell
TARGET = from_vector([0.05, 0.02, 0.12, 0.3, 0.2, -0.4])  # T_tip_target


def mock(kind, model, m=30):
    q = configurations(model, m)
    T = tip_true(model, truth(model), q)
    if kind == 'pose':
        return Measurements('pose', q, values=BASE @ T @ TARGET)
    if kind == 'points':
        offsets = np.array([[0.05, 0.0, 0.10], [-0.04, 0.06, 0.08]])
        marker = np.arange(m) % 2
        p = np.einsum('mij,mj->mi', T[:, :3, :3], offsets[marker]) + T[:, :3, 3]
        return Measurements('points', q, marker, p @ BASE[:3, :3].T + BASE[:3, 3],
                            ball=[0.0, 0.0, 0.09])
    raise AssertionError(kind)


@pytest.mark.parametrize('kind', ['pose', 'points'])
def test_noise_free_recovers_the_true_joint_origins_held_out(ur10e, kind):
    data = mock(kind, ur10e)
    cv = mf.cross_validate(mf.ErrorModel(ur10e, 'full'), data, mf.kfold(len(data), 3))
    assert cv.nominal['max_mm'] > 0.5                      # the errors show
    assert cv.calibrated['max_mm'] < 1e-6                  # and are gone, held out
    if kind == 'pose':
        assert cv.calibrated['rot_rms_mrad'] < 1e-6
    else:
        assert cv.calibrated['rot_rms_mrad'] is None


def test_spheres_with_a_known_distance_recover_held_out(ur10e):
    """Three spheres, ball 0.1 m off the flange; relative data: the base is free."""
    rng = np.random.default_rng(5)
    params = truth(ur10e)
    ball = np.array([0.01, -0.02, 0.10])
    centres = np.array([[0.6, 0.2, 0.1], [0.5, -0.4, 0.2], [0.2, 0.5, 0.4]])
    q, sphere = [], []
    from cobot_calib_ros.core.kinematics.ik import solve_ik
    for s, c in enumerate(centres):
        for _ in range(12):
            R = from_vector([0, 0, 0, *rng.normal(0, 0.6, 3)])[:3, :3] @ np.diag([1, -1, -1])
            target = np.eye(4)
            target[:3, :3], target[:3, 3] = R, c - R @ ball
            result = solve_ik(ur10e.chain(params), target, rng.uniform(-1, 1, 6),
                              position_only=False)
            if result:
                q.append(result.q)
                sphere.append(s)
    q, sphere = np.array(q), np.array(sphere)
    p = tip_true(ur10e, params, q)
    assert np.abs(np.einsum('mij,j->mi', p[:, :3, :3], ball) + p[:, :3, 3]
                  - centres[sphere]).max() < 1e-9            # the mock is consistent
    data = Measurements('spheres', q, sphere,
                        distances=[(0, 1, float(np.linalg.norm(centres[0] - centres[1])))],
                        ball=[0.0, 0.0, 0.1])
    cv = mf.cross_validate(mf.ErrorModel(ur10e, 'full'), data, mf.kfold(len(data), 3))
    assert cv.nominal['max_mm'] > 0.3
    assert cv.calibrated['max_mm'] < 1e-6


def test_touches_on_two_planes_recover_held_out(ur10e):
    """The ball touches a table (z = 0.05 m) and a wall tilted 60 deg; planes unknown."""
    from cobot_calib_ros.core.kinematics.ik import solve_ik
    rng = np.random.default_rng(6)
    params = truth(ur10e)
    ball = np.array([0.02, 0.01, 0.12])
    planes = [(np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.1, 0.05])),
              (np.array([np.sin(1.05), 0.0, np.cos(1.05)]), np.array([0.5, -0.3, 0.4]))]
    q, plane = [], []
    for k, (n, point) in enumerate(planes):
        u = np.cross(n, [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        while plane.count(k) < 20:
            target = np.eye(4)
            target[:3, :3] = from_vector([0, 0, 0, *rng.normal(0, 0.5, 3)])[:3, :3] \
                @ np.diag([1, -1, -1])
            c = point + rng.uniform(-0.2, 0.2) * u + rng.uniform(-0.2, 0.2) * v
            target[:3, 3] = c - target[:3, :3] @ ball
            result = solve_ik(ur10e.chain(params), target, rng.uniform(-1, 1, 6))
            if result:
                q.append(result.q)
                plane.append(k)
    data = Measurements('plane', np.array(q), np.array(plane), ball=[0.0, 0.0, 0.1])
    cv = mf.cross_validate(mf.ErrorModel(ur10e, 'full'), data, mf.kfold(len(data), 4))
    assert cv.nominal['max_mm'] > 0.3
    # two planes see two of the lengths only through the others (about +- 1 mm from the fit
    # with the prior): since issue 37 they are held at nominal with their true errors, and
    # the rest is recovered: 2.30 -> 0.78 mm max (< 1e-6 mm before, noise-free only)
    assert [f['held'] for f in cv.folds] == [2, 2, 2, 2]
    assert cv.calibrated['max_mm'] < 0.4 * cv.nominal['max_mm']


def test_a_ur10e_on_a_vertical_lift_prismatic_joint(ur10e):
    """The base joint made a prismatic lift (0..0.4 m along z, axis tilted 0.05 rad): the
    lift's origin errors are identified with the arm's; 4 R + 2 P + 6 = 32 kept."""
    text = UR10E.read_text().replace(
        '<joint name="base_link-base_link_inertia" type="fixed">',
        '<joint name="base_link-base_link_inertia" type="prismatic"><axis xyz="0.05 0 1"/>'
        '<limit lower="0" upper="0.4" effort="0" velocity="0"/>', 1)
    model = model_from_urdf(text, 'base_link', 'wrist_3_link', 'ur10e_lift')
    assert model.prismatic.tolist() == [True] + [False] * 6
    rng = np.random.default_rng(8)
    q = np.hstack([rng.uniform(0.0, 0.4, (30, 1)), configurations(ur10e, 30)])
    T = fk(model.chain(truth(model, seed=9)), q)
    data = Measurements('pose', q, values=BASE @ T @ TARGET)
    ident = mf.identifiable(mf.ErrorModel(model, 'full'), data)
    assert ident.parameters_kept == ident.minimum == 4 * 6 + 2 + 6
    cv = mf.cross_validate(mf.ErrorModel(model, 'full'), data, mf.kfold(len(data), 3))
    assert cv.nominal['max_mm'] > 0.5 and cv.calibrated['max_mm'] < 1e-6


def test_identifiability_of_a_full_pose_model_is_the_textbook_minimum(ur10e):
    ident = mf.identifiable(mf.ErrorModel(ur10e, 'full'), mock('pose', ur10e))
    assert ident.minimum == 4 * 6 + 6 == ident.parameters_kept
    assert len(ident.kept) == 18 and ident.frame_dofs == 12
    dropped = {d.name: d.reason for d in ident.dropped}
    assert set(dropped) >= {f'{c}_shoulder_pan_joint' for c in ('x', 'y', 'z', 'yaw')}
    assert 'base_x' in dropped['x_shoulder_pan_joint']     # the base frame took it
    again = mf.identifiable(mf.ErrorModel(ur10e, 'full'), mock('pose', ur10e))
    assert again.kept == ident.kept                          # deterministic
    assert 1.0 < ident.condition_number < 1e4


def test_offsets_model_keeps_all_but_the_first_and_last_joint(ur10e):
    """The first joint's offset turns the base frame, the last one's the target frame."""
    ident = mf.identifiable(mf.ErrorModel(ur10e, 'offsets'), mock('pose', ur10e))
    assert ident.kept == tuple(f'offset_{j}' for j in ur10e.joint_names[1:-1])
    assert [d.name for d in ident.dropped] == ['offset_shoulder_pan_joint',
                                               'offset_wrist_3_joint']
    assert 'base_rz' in ident.dropped[0].reason and 'target_' in ident.dropped[1].reason


def test_folds_and_groups():
    assert [f.tolist() for f in mf.kfold(7, 3)] == [[0, 3, 6], [1, 4], [2, 5]]
    names, rows = mf.by_group(['b', 'a', 'b', 'c'])
    assert names == ('b', 'a', 'c') and [r.tolist() for r in rows] == [[0, 2], [1], [3]]
    assert [r.tolist() for r in mf.held_out_rows(np.array([0, 0, 1, 2, 2]),
                                                 [np.array([0, 2]), np.array([1])])] \
        == [[0, 1, 3, 4], [2]]
    with pytest.raises(ValueError, match='--folds 1'):
        mf.kfold(5, 1)
    with pytest.raises(ValueError, match='at least 2 groups'):
        mf.by_group(['a', 'a'])


def test_outlier_rule_names_the_bad_row():
    e = np.array([1.0, 1.1, 0.9, 1.05, 0.95, 4.0, 1.0]) * 1e-3
    assert mf.outliers(e) == [5]
    assert mf.outliers(e[:5]) == []


def test_too_few_rows_for_the_parameters_is_refused(ur10e):
    data = mock('pose', ur10e, m=4)
    with pytest.raises(ValueError, match=r'4 rows give 24 equations for 30 unknowns'):
        mf.fit(mf.ErrorModel(ur10e, 'full'), data, tuple(ur10e.parameter_names[6:24]))


def test_error_model_must_fit_the_model_kind(ur10e):
    with pytest.raises(ValueError, match=r'--model mdh needs a DH table \(--dh FILE\)'):
        mf.ErrorModel(ur10e, 'mdh')


def test_dh_table_gives_the_standard_dh_product():
    def rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    def rx(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])

    def tr(x, z):
        T = np.eye(4)
        T[0, 3], T[2, 3] = x, z
        return T
    dh = np.array([[0.1, 0.2, 0.3, -1.2], [-0.475, -1.5, 0.05, 0.4]])
    model = dh_model('two', ('j1', 'j2'), dh, [(-3, 3)] * 2)
    q = np.array([0.3, -0.7])
    expected = np.eye(4)
    for (d, theta, r, alpha), qi in zip(dh, q):
        expected = expected @ rz(theta + qi) @ tr(0, d) @ tr(r, 0) @ rx(alpha)
    np.testing.assert_allclose(fk(model.chain(), q), expected, atol=1e-15)
