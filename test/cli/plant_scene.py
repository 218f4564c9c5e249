"""A plant's UR5e-like arm with planted errors, and the files a plant engineer has for it: a
tracker CSV (one reflector on tool0, in the tracker's frame, with noise), the reference points
of a fixture touched with the tool (joints, as read off the pendant), a program in the fixture's
user frame, and a minimal cell file (no layouts, no simulation).

``python test/cli/plant_scene.py DIR`` writes them to DIR (test/data/plant-ur5e holds them for
the README walk-through); test_plant_path.py writes them to a temporary folder and knows the
truth (:data:`PLANTED`, :data:`T_BASE_USER`, the noise).
"""
from __future__ import annotations

from pathlib import Path
import shutil
import sys

import numpy as np

from cobot_calib_ros.core.frames import from_xyz_rpy, to_pose
from cobot_calib_ros.core.kinematics import fk, solve_ik
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf

URDF = Path(__file__).resolve().parents[1] / 'data' / 'plant-ur5e' / 'ur5e.urdf'
MODEL = model_from_urdf(URDF.read_text(), 'base_link', 'tool0', 'ur5e', free_pitch=True)
# the real arm's deviations from its drawing [m, rad]: links, zero offsets, a tilted shoulder;
# none in the last joint's placement, which one reflector cannot see (the report names it)
PLANTED = {'z_shoulder_pan_joint': 0.35e-3, 'roll_shoulder_lift_joint': 0.8e-3,
           'x_elbow_joint': 0.6e-3, 'yaw_elbow_joint': 1.2e-3, 'x_wrist_1_joint': -0.5e-3,
           'z_wrist_1_joint': 0.3e-3, 'yaw_wrist_1_joint': -0.7e-3,
           'yaw_wrist_2_joint': 0.9e-3}
TRUE_PARAMS = MODEL.nominal + np.array([PLANTED.get(n, 0.0) for n in MODEL.parameter_names])
HOME = np.array([0.0, -1.9, 1.9, -1.5708, -1.5708, 0.0])
TOOL = from_xyz_rpy([0.0, 0.0, 0.12], [0.0, 0.0, 0.0])        # a probe on tool0
NOISE_SD = 0.015e-3              # [m] per axis: the tracker's and a touch's
NOISE_RMS = NOISE_SD * np.sqrt(3.0)   # one point's RMS error [m]: the noise floor
REFLECTOR = np.array([0.01, 0.0, 0.05])                        # in tool0 [m]
T_TRACKER_BASE = from_xyz_rpy([2.1, -0.4, 0.35], [0.01, -0.02, 2.6])
T_BASE_USER = from_xyz_rpy([0.42, -0.12, 0.03], [0.004, -0.003, 0.3])  # the fixture, true
FIXTURE = {'F1': (0.0, 0.0, 0.0), 'F2': (0.25, 0.0, 0.0), 'F3': (0.25, 0.18, 0.0),
           'F4': (0.0, 0.18, 0.0), 'F5': (0.12, 0.09, 0.0)}
DOWN = from_xyz_rpy([0, 0, 0], [np.pi, 0.0, 0.0])             # tool z down in the user frame
CELL = """# A plant's cell: robot, tool, frames and home, nothing for the mock (no layouts, no
# simulation): test/cli/plant_scene.py, README "A plant's path"
cell:
  name: plant_ur5e
  robot: {urdf: ur5e.urdf, base_link: base_link, tip_link: tool0}
  base_frame: base_link
  tool_frame: tool0
  user_frame: fixture
  home: [0.0, -1.9, 1.9, -1.5708, -1.5708, 0.0]
  T_flange_tool: {xyz: [0.0, 0.0, 0.12], rpy: [0.0, 0.0, 0.0]}
"""


def true_chain(tool=TOOL):
    return MODEL.chain(TRUE_PARAMS, tool=tool)


def program_targets() -> dict[str, np.ndarray]:
    """The program: T_user_tool of each target (tool down, over the fixture) [m]."""
    out = {}
    for k, (x, y, z, yaw) in enumerate([(0.05, 0.03, 0.05, 0.0), (0.20, 0.03, 0.02, 0.4),
                                        (0.22, 0.15, 0.08, -0.3), (0.04, 0.16, 0.03, 0.9),
                                        (0.13, 0.09, 0.12, -0.8), (0.30, 0.10, 0.06, 0.2)]):
        out[f'wp{k + 1}'] = from_xyz_rpy([x, y, z], [0, 0, 0]) @ DOWN @ \
            from_xyz_rpy([0, 0, 0], [0, 0, yaw])
    return out


def _ik(chain, T, seed=HOME):
    result = solve_ik(chain, T, seed)
    assert result, result.message
    return result.q


def write(folder: Path, seed: int = 37) -> dict[str, Path]:
    """The scene's files in ``folder``; their paths by name."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {'urdf': folder / 'ur5e.urdf', 'tracker': folder / 'tracker.csv',
             'sidecar': folder / 'tracker.yaml', 'points': folder / 'fixture_points.csv',
             'program': folder / 'program.csv', 'cell': folder / 'plant_ur5e.yaml'}
    if URDF.resolve() != paths['urdf'].resolve():
        shutil.copyfile(URDF, paths['urdf'])
    q = HOME + rng.uniform(-0.6, 0.6, (80, 6))
    tool0 = fk(true_chain(np.eye(4)), q)
    p = np.einsum('ij,mj->mi', T_TRACKER_BASE[:3, :3],
                  np.einsum('mij,j->mi', tool0[:, :3, :3], REFLECTOR) + tool0[:, :3, 3]) \
        + T_TRACKER_BASE[:3, 3] + rng.normal(0.0, NOISE_SD, (80, 3))
    joints = ','.join(MODEL.joint_names)
    paths['tracker'].write_text(f'{joints},x,y,z\n' + ''.join(
        ','.join(repr(float(v)) for v in (*qi, *pi)) + '\n' for qi, pi in zip(q, p)))
    paths['sidecar'].write_text(
        'measurement: points\nunits: {length: m, angle: rad}\n'
        f'joints: [{", ".join(MODEL.joint_names)}]\n'
        'frames: {measured_in: tracker, base: base_link, tip: tool0, target: reflector}\n'
        'markers: {reflector: [x, y, z]}\n'
        f'noise: {float(NOISE_RMS)!r}   # one point\'s RMS error [m]\n')
    lines = []
    for name, p_user in FIXTURE.items():
        touched = T_BASE_USER @ from_xyz_rpy(np.array(p_user) + rng.normal(0.0, NOISE_SD, 3),
                                             [0, 0, 0]) @ DOWN
        qi = _ik(true_chain(), touched)
        lines.append(','.join([name, *(repr(float(v)) for v in p_user),
                               *(repr(float(v)) for v in qi)]))
    paths['points'].write_text(f'name,user_x,user_y,user_z,{joints}\n' + '\n'.join(lines)
                               + '\n')
    paths['program'].write_text('name,x,y,z,qx,qy,qz,qw\n' + ''.join(
        f'{name},' + ','.join(repr(float(v)) for v in np.concatenate(to_pose(T))) + '\n'
        for name, T in program_targets().items()))
    paths['cell'].write_text(CELL)
    return paths


if __name__ == '__main__':
    for name, path in write(Path(sys.argv[1])).items():
        print(f'{name}: {path}')
