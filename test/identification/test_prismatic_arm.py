"""Issue 28 item 6: a 7R+1P arm measured by three mocap markers keeps the textbook minimum of
parameters (39). An arm of our own: a lift (prismatic, vertical) under a 7R arm whose axes
alternate z, y, x, y, x, y, x (Fetch-like), written as a URDF with literal axes; the data are
computed here from the URDF's joints (numpy, not the project's model) and written as a
measurement file in millimetres and degrees, as a mocap export is.

Two causes of a parameter lost, both shown: (1) a joint with axis y after one with axis x
converts to a placement with pitch -pi/2 (gimbal lock: its roll and yaw turn about one axis,
the rank test drops one of them; two such joints here); (2) the lift's column was read in
units.angle (x pi/180 instead of x 1e-3 for mm), a slide 57 times too short."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from cobot_calib_ros.api.identification import identify_source
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf

AXES = {'x': (1, 0, 0), 'y': (0, 1, 0), 'z': (0, 0, 1)}
# name, type, xyz [m], axis, limits [m or rad]
JOINTS = [('torso_lift', 'prismatic', (-0.086875, 0.0, 0.37743), 'z', (0.0, 0.386)),
          ('shoulder_pan', 'revolute', (0.119525, 0.0, 0.34858), 'z', (-1.6, 1.6)),
          ('shoulder_lift', 'revolute', (0.117, 0.0, 0.06), 'y', (-1.2, 1.5)),
          ('upperarm_roll', 'revolute', (0.219, 0.0, 0.0), 'x', (-3.0, 3.0)),
          ('elbow_flex', 'revolute', (0.133, 0.0, 0.0), 'y', (-2.2, 2.2)),
          ('forearm_roll', 'revolute', (0.197, 0.0, 0.0), 'x', (-3.0, 3.0)),
          ('wrist_flex', 'revolute', (0.1245, 0.0, 0.0), 'y', (-2.1, 2.1)),
          ('wrist_roll', 'revolute', (0.1385, 0.0, 0.0), 'x', (-3.0, 3.0))]
TOOL = (0.16645, 0.0, 0.0)
MARKERS = np.array([[0.05, 0.0, 0.04], [0.02, 0.05, 0.0], [0.03, -0.04, -0.03]])  # on tool
WORLD = np.array([1.2, -0.4, 0.1])        # the mocap origin's offset from the base [m]
NOISE_M = 0.1e-3                           # per axis
MINIMUM = 4 * 7 + 2 * 1 + 6 - 3 + 3 * 2   # Everett 4R + 2P + 6, less the unseen marker
                                           # orientation, plus 3 per further marker


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _turn(axis, angle):
    k = np.asarray(axis, dtype=float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def true_origins(seed=3):
    """(8 + 1, 6) xyz rpy of the true arm: the nominal with 0.1-0.5 mm and 0.5-2 mrad errors."""
    rng = np.random.default_rng(seed)
    o = np.array([list(j[2]) + [0.0, 0.0, 0.0] for j in JOINTS] + [list(TOOL) + [0, 0, 0]])
    o[:, :3] += rng.choice([-1, 1], o[:, :3].shape) * rng.uniform(0.1e-3, 0.5e-3, (9, 3))
    o[:, 3:] += rng.choice([-1, 1], o[:, 3:].shape) * rng.uniform(0.5e-3, 2e-3, (9, 3))
    return o


def fk(origins, q):
    """(m, 4, 4) T_base_tool of the URDF with these joint origins."""
    out = []
    for row in q:
        T = np.eye(4)
        for i, origin in enumerate(origins):
            A = np.eye(4)
            A[:3, :3], A[:3, 3] = _rpy(*origin[3:]), origin[:3]
            T = T @ A
            if i < len(JOINTS):
                M = np.eye(4)
                axis = AXES[JOINTS[i][3]]
                if JOINTS[i][1] == 'prismatic':
                    M[:3, 3] = np.multiply(axis, row[i])
                else:
                    M[:3, :3] = _turn(axis, row[i])
                T = T @ M
        out.append(T)
    return np.array(out)


def urdf():
    links = ['base_link'] + [f'link_{i}' for i in range(len(JOINTS))] + ['tool']
    parts = ['<robot name="lift7">'] + [f'  <link name="{n}"/>' for n in links]
    for i, (name, kind, xyz, axis, (lo, hi)) in enumerate(JOINTS + [('tool_joint', 'fixed',
                                                                       TOOL, 'x', (0, 0))]):
        limit = '' if kind == 'fixed' else \
            f'<limit lower="{lo}" upper="{hi}" effort="1" velocity="1"/>'
        parts.append(f'  <joint name="{name}" type="{kind}"><parent link="{links[i]}"/>'
                     f'<child link="{links[i + 1]}"/><origin xyz="{" ".join(map(str, xyz))}" '
                     f'rpy="0 0 0"/><axis xyz="{" ".join(map(str, AXES[axis]))}"/>{limit}'
                     '</joint>')
    return '\n'.join(parts + ['</robot>'])


def write_file(folder, m=60, seed=4):
    """A mocap export: joints in deg (the lift in mm), markers in mm, three per row."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([j[4] for j in JOINTS]).T
    q = lo + rng.uniform(0.05, 0.95, (m, len(JOINTS))) * (hi - lo)
    T = fk(true_origins(), q)
    cells = [np.degrees(q[:, 1:])]
    header = [j[0] for j in JOINTS]
    for k, marker in enumerate(MARKERS):
        p = T[:, :3, :3] @ marker + T[:, :3, 3] + WORLD + rng.normal(0, NOISE_M, (m, 3))
        cells.append(p * 1e3)
        header += [f'm{k}_{c}' for c in 'xyz']
    rows = np.hstack([q[:, :1] * 1e3] + cells)
    csv = folder / 'lift7.csv'
    csv.write_text(','.join(header) + '\n' + '\n'.join(','.join(repr(float(v)) for v in r)
                                                       for r in rows) + '\n')
    (folder / 'lift7.yaml').write_text(yaml.safe_dump({
        'measurement': 'points', 'units': {'length': 'mm', 'angle': 'deg'},
        'joints': [j[0] for j in JOINTS],
        'frames': {'measured_in': 'mocap', 'base': 'base_link', 'tip': 'tool'},
        'markers': {f'm{k}': [f'm{k}_{c}' for c in 'xyz'] for k in range(3)},
        'ball': [30.0, 0.0, 0.0]}, sort_keys=False))
    (folder / 'lift7.urdf').write_text(urdf())
    return csv, q


@pytest.fixture(scope='module')
def scene(tmp_path_factory):
    return write_file(tmp_path_factory.mktemp('lift7'))


def test_the_scene_is_the_urdf():
    """The generator's FK of the nominal origins is the project's FK of the URDF."""
    from cobot_calib_ros.core.kinematics.model import fk as model_fk
    nominal = np.array([list(j[2]) + [0, 0, 0] for j in JOINTS] + [list(TOOL) + [0, 0, 0]])
    q = np.random.default_rng(5).uniform(-1.5, 1.5, (10, 8))
    q[:, 0] = np.abs(q[:, 0]) * 0.2
    for free in (False, True):
        model = model_from_urdf(urdf(), 'base_link', 'tool', 'lift7', free_pitch=free)
        assert list(model.prismatic) == [True] + [False] * 7
        assert np.abs(model_fk(model.chain(), q) - fk(nominal, q)).max() < 1e-12


def test_the_literal_conversion_puts_two_joints_at_gimbal_lock():
    """Cause 1: axis y after axis x converts to pitch -pi/2 (elbow_flex, wrist_flex); with
    free_pitch (what identification uses) no placement is beyond 60 deg of pitch."""
    pitch = model_from_urdf(urdf(), 'base_link', 'tool', 'lift7').rows()[:, 4]
    assert np.sum(np.isclose(np.abs(pitch), np.pi / 2)) == 2
    free = model_from_urdf(urdf(), 'base_link', 'tool', 'lift7', free_pitch=True).rows()
    assert np.abs(free[:, 4]).max() < np.radians(60)


def test_parameters_kept_is_the_textbook_minimum(scene):
    """39 kept of 39 (37 with the gimbal-locked frames, at any rank tolerance down to 1e-7:
    the parametrisation, not the tolerance); the lift read in mm; held out at the noise
    floor (3 markers x 0.1 mm per axis: 0.173 mm RMS)."""
    from cobot_calib_ros.loaders.measurements import load_measurements
    csv, q = scene
    r = identify_source(csv, measurement='points', urdf=str(csv.with_suffix('.urdf')),
                        folds=5)
    assert r['parameters_minimum'] == MINIMUM == 39
    assert r['parameters_kept'] == MINIMUM
    assert r['verdict']['passed'] and r['converged']
    assert r['held_out']['nominal']['rmse_mm'] > 1.0
    assert r['held_out']['calibrated']['rmse_mm'] < 1.3 * np.sqrt(3) * NOISE_M * 1e3
    locked = model_from_urdf(urdf(), 'base_link', 'tool', 'lift7')
    file = load_measurements(csv).in_joint_order(locked.joint_names, locked.prismatic)
    assert file.measurements.q[:, 0] == pytest.approx(q[np.asarray(file.sample), 0], abs=1e-12)
    for tol in (mf.RANK_TOL, 1e-7):
        assert mf.identifiable(mf.ErrorModel(locked, 'full'), file.measurements,
                               tol).parameters_kept == MINIMUM - 2
