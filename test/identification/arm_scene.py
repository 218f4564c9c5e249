"""A 6-axis arm of our own for the trust tests: its URDF written from a DH table (UR5e-sized),
a "true" copy with small errors, and measurement files written as the README says, from a
forward kinematics computed here (numpy on the URDF's joint origins; not the project's model).

The errors are what a real arm has: origins 0.1-0.5 mm, tilts 0.5-2 mrad, zero offsets ~1 mrad.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

# UR5e DH (d, a, alpha): the joint origins of the URDF below are the DH transforms
DH = [(0.1625, 0.0, np.pi / 2), (0.0, -0.425, 0.0), (0.0, -0.3922, 0.0),
      (0.1333, 0.0, np.pi / 2), (0.0997, 0.0, -np.pi / 2), (0.0996, 0.0, 0.0)]
JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
          'wrist_2_joint', 'wrist_3_joint']
LINKS = ['base_link', 'shoulder_link', 'upper_arm_link', 'forearm_link', 'wrist_1_link',
         'wrist_2_link', 'wrist_3_link', 'tool0']


def nominal_origins() -> np.ndarray:
    """(7, 6) xyz rpy of each joint's origin (6 revolute + the fixed tool0 joint): joint i's
    origin is the DH transform of row i-1 (Rz(theta) Tz(d) Tx(a) Rx(alpha) with theta = 0)."""
    rows = [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]
    for d, a, alpha in DH:
        rows.append([a, 0.0, d, alpha, 0.0, 0.0])
    return np.array(rows)


def true_origins(seed: int = 11) -> tuple[np.ndarray, np.ndarray]:
    """(origins (7, 6), zero offsets (6,)) of the true arm: the nominal with small errors."""
    rng = np.random.default_rng(seed)
    o = nominal_origins()
    o[:, :3] += rng.choice([-1, 1], (7, 3)) * rng.uniform(0.1e-3, 0.5e-3, (7, 3))
    o[:, 3:] += rng.choice([-1, 1], (7, 3)) * rng.uniform(0.5e-3, 2e-3, (7, 3))
    return o, rng.normal(0.0, 1e-3, 6)


def urdf(origins: np.ndarray | None = None, name: str = 'arm6') -> str:
    o = nominal_origins() if origins is None else origins
    parts = [f'<?xml version="1.0"?>\n<robot name="{name}">']
    parts += [f'  <link name="{link}"/>' for link in LINKS]
    for i in range(7):
        kind = 'revolute' if i < 6 else 'fixed'
        jname = JOINTS[i] if i < 6 else 'tool0_joint'
        xyz = ' '.join(repr(float(v)) for v in o[i, :3])
        rpy = ' '.join(repr(float(v)) for v in o[i, 3:])
        body = f'    <origin xyz="{xyz}" rpy="{rpy}"/>\n'
        if kind == 'revolute':
            body += ('    <axis xyz="0 0 1"/>\n    <limit lower="-6.283185" upper="6.283185" '
                     'effort="150" velocity="3.14"/>\n')
        parts.append(f'  <joint name="{jname}" type="{kind}">\n    <parent link="{LINKS[i]}"/>'
                     f'\n    <child link="{LINKS[i + 1]}"/>\n{body}  </joint>')
    parts.append('</robot>\n')
    return '\n'.join(parts)


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def fk(origins: np.ndarray, offsets: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(m, 4, 4) T_base_tool0 of the arm with ``origins`` at joint angles q + offsets."""
    out = []
    for row in np.atleast_2d(q) + offsets:
        T = np.eye(4)
        for i in range(7):
            A = np.eye(4)
            A[:3, :3], A[:3, 3] = _rpy(*origins[i, 3:]), origins[i, :3]
            T = T @ A
            if i < 6:
                c, s = np.cos(row[i]), np.sin(row[i])
                T = T @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        out.append(T)
    return np.array(out)


def configurations(m: int, seed: int = 12) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (m, 6))
    q[:, 1] = rng.uniform(-2.6, -0.6, m)        # shoulder up: the arm above its base
    q[:, 2] = rng.uniform(0.4, 2.4, m) * rng.choice([-1, 1], m)
    return q


def write(folder: Path, name: str, sidecar: dict, header: list[str], rows) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    csv = folder / f'{name}.csv'
    lines = [','.join(header)] + [','.join(c if isinstance(c, str) else repr(float(c))
                                           for c in r) for r in rows]
    csv.write_text('\n'.join(lines) + '\n')
    (folder / f'{name}.yaml').write_text(yaml.safe_dump(sidecar, sort_keys=False))
    return csv


BASE = np.array([[0.0, -1.0, 0.0, 1.5], [1.0, 0.0, 0.0, 0.4], [0.0, 0.0, 1.0, 0.2],
                 [0.0, 0.0, 0.0, 1.0]])           # T_tracker_base
MARKER = np.array([0.03, -0.02, 0.09])           # on tool0


def points_file(folder: Path, m: int = 60, noise_m: float = 50e-6, *, length: str = 'm',
                scale: float = 1.0, angle: str = 'rad', angle_scale: float = 1.0,
                seed: int = 13, zeroing: np.ndarray | None = None,
                q: np.ndarray | None = None) -> Path:
    """A tracker measures one marker on tool0: positions [m] x ``scale`` in the CSV, joints
    [rad] x ``angle_scale``, the sidecar declaring ``length`` and ``angle``; ``zeroing``
    (6,) [rad] added to the true arm's zero offsets (an encoder zeroed off), ``q`` (m, 6)
    [rad] the configurations (default :func:`configurations`)."""
    origins, offsets = true_origins()
    offsets = offsets if zeroing is None else offsets + zeroing
    q = configurations(m) if q is None else q
    T = BASE @ fk(origins, offsets, q)
    p = T[:, :3, :3] @ MARKER + T[:, :3, 3]
    p += np.random.default_rng(seed).normal(0.0, noise_m, p.shape)
    side = {'measurement': 'points', 'units': {'length': length, 'angle': angle},
            'joints': list(JOINTS),
            'frames': {'measured_in': 'tracker', 'base': 'base_link', 'tip': 'tool0'},
            'markers': {'m1': ['x', 'y', 'z']}, 'ball': [float(v * scale) for v in MARKER]}
    header = side['joints'] + ['x', 'y', 'z']
    rows = np.hstack([q * angle_scale, p * scale])
    return write(folder, 'points', side, header, rows)


def pose_file(folder: Path, m: int = 60, noise_m: float = 50e-6, noise_rad: float = 0.2e-3,
              *, length: str = 'm', scale: float = 1.0, seed: int = 14) -> Path:
    """A fixed camera (here: BASE) measures a board on tool0 (rpy rotation)."""
    from scipy.spatial.transform import Rotation
    origins, offsets = true_origins()
    q = configurations(m)
    board = np.eye(4)
    board[:3, 3] = [0.02, 0.04, 0.08]
    T = BASE @ fk(origins, offsets, q) @ board
    rng = np.random.default_rng(seed)
    p = T[:, :3, 3] + rng.normal(0.0, noise_m, (m, 3))
    R = Rotation.from_matrix(T[:, :3, :3]) * Rotation.from_rotvec(rng.normal(0, noise_rad, (m, 3)))
    side = {'measurement': 'pose', 'units': {'length': length, 'angle': 'rad'},
            'joints': list(JOINTS),
            'frames': {'measured_in': 'camera', 'base': 'base_link', 'tip': 'tool0',
                       'target': 'board'},
            'position': ['x', 'y', 'z'], 'rotation': ['rx', 'ry', 'rz'],
            'rotation_format': 'rpy', 'camera': 'fixed'}
    rows = np.hstack([q, p * scale, R.as_euler('xyz')])
    return write(folder, 'pose', side, side['joints'] + ['x', 'y', 'z', 'rx', 'ry', 'rz'], rows)


PLANES = [(np.array([0.0, 0.0, 1.0]), 0.05), (np.array([0.0, 0.8, 0.6]), 0.30)]   # n . p = d


def plane_file(folder: Path, m: int = 60, noise_m: float = 25e-6, seed: int = 15) -> Path:
    """A ball on tool0 touches two planes (base frame): joint 2 of each random configuration
    is solved so that the ball centre is ``noise`` off its plane."""
    from scipy.optimize import brentq
    origins, offsets = true_origins()
    rng = np.random.default_rng(seed)
    ball = MARKER
    rows = []
    while len(rows) < m:
        k = len(rows) % 2
        n, d = PLANES[k]
        q = configurations(1, seed=int(rng.integers(1 << 30)))[0]
        target = d + rng.normal(0.0, noise_m)

        def off(q2):
            qq = q.copy()
            qq[1] = q2
            T = fk(origins, offsets, qq)[0]
            return n @ (T[:3, :3] @ ball + T[:3, 3]) - target
        grid = np.linspace(-3.0, 0.0, 61)
        values = [off(g) for g in grid]
        roots = [brentq(off, a, b, xtol=1e-14) for a, b, fa, fb in
                 zip(grid[:-1], grid[1:], values[:-1], values[1:]) if fa * fb < 0]
        if not roots:
            continue
        q[1] = roots[0]
        rows.append([*q, k])
    side = {'measurement': 'plane', 'units': {'length': 'm', 'angle': 'rad'},
            'joints': list(JOINTS),
            'frames': {'base': 'base_link', 'tip': 'tool0'}, 'plane': 'plane',
            'ball': [float(v) for v in ball]}
    return write(folder, 'plane', side, side['joints'] + ['plane'],
                 [[*r[:6], str(int(r[6]))] for r in rows])


def workspace_error(identified: list[dict], m: int = 500, seed: int = 99) -> float:
    """RMS distance [m] of the ball (MARKER on tool0) of the URDF's arm with the
    ``identified`` parameters (a report's list: name, value; none: nominal) from the true
    arm's over ``m`` configurations, the best rigid fit between the two removed."""
    from cobot_calib_ros.core.frames import kabsch
    from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
    from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
    errors = mf.ErrorModel(model_from_urdf(urdf(), 'base_link', 'tool0', 'arm6'), 'full')
    q = configurations(m, seed)
    T = errors.tip_poses(tuple(p['name'] for p in identified),
                         np.array([p['value'] for p in identified]), q)
    truth = fk(*true_origins(), q)
    p, t = (F[:, :3, :3] @ MARKER + F[:, :3, 3] for F in (T, truth))
    fitted = kabsch(p, t)
    return float(np.sqrt(np.mean(np.sum((p @ fitted[:3, :3].T + fitted[:3, 3] - t) ** 2,
                                        axis=1))))


def urdf_file(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / 'arm6.urdf'
    path.write_text(urdf())
    return path
