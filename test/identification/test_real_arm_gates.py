"""Issue 37 item 4, must-show 3: each parameter judged by what the data say about it. The
arm of test_trust_gates (arm_scene: a UR5e-sized URDF, a true copy off by 0.1-0.5 mm,
0.5-2 mrad and ~1 mrad zero offsets, forward kinematics computed independently), one marker
measured by a tracker (50 um per axis: held-out floor 0.087 mm RMS), identified as a user
runs `cobot-calib identify --measurement`."""
from __future__ import annotations

import json

import numpy as np

from cobot_calib_ros.cli.main import main

import arm_scene as scene

FLOOR_MM = 0.0866


def identify(capsys, csv, urdf, *extra: str) -> tuple[int, dict, str]:
    code = main(['identify', '--measurement', 'points', '--source', str(csv), '--urdf',
                 str(urdf), '--tip-link', 'tool0', *extra])
    out, err = capsys.readouterr()
    return code, (json.loads(out) if '--json' in extra else out), err


def test_a_well_determined_large_zero_offset_is_accepted_and_reported(capsys, tmp_path):
    """Joint 4 (wrist_1) zeroed 61 mrad off (3.5 deg): the 50 mrad bound refused this arm
    before; now its zero offset (the URDF origin's yaw: the joint turns about its own axis)
    is determined to +- 0.06 mrad, kept, reported as large, and the arm calibrates to the
    noise floor."""
    urdf = scene.urdf_file(tmp_path)
    zeroing = np.array([0.0, 0.0, 0.0, 0.061, 0.0, 0.0])
    csv = scene.points_file(tmp_path / 'data', zeroing=zeroing)
    code, r, err = identify(capsys, csv, urdf, '--json')
    assert code == 0, err
    assert r['verdict']['passed'] and r['converged'] and r['held'] == []
    yaw = next(p for p in r['identified'] if p['name'] == 'yaw_wrist_1_joint')
    assert 0.055 < yaw['delta'] < 0.067 and yaw['std'] < 0.2e-3
    assert [n for n in r['large'] if n.startswith('yaw_wrist_1_joint')] == \
        [f'yaw_wrist_1_joint {yaw["delta"] * 1e3:+.4g} mrad +- {yaw["std"] * 1e3:.2g}: large, '
         'typical of encoder zeroing']
    assert r['held_out']['nominal']['rmse_mm'] > 5.0                 # 10.0 mm
    assert r['held_out']['calibrated']['rmse_mm'] < 1.5 * FLOOR_MM
    # the text summary says it where the user reads
    code, out, _ = identify(capsys, csv, urdf)
    assert code == 0 and 'large: yaw_wrist_1_joint +61' in out
    assert 'typical of encoder zeroing' in out


def test_an_undetermined_parameter_is_held_at_nominal_and_the_calibration_passes(capsys,
                                                                                 tmp_path):
    """The last joint turned by at most 0.02 rad over 40 poses: its origin's x is barely seen
    (+- 0.97 mm from the fit, against the 1 mm a real arm deviates by). It is held at nominal,
    named with the reason, and the rest calibrates: held out 1.33 -> 0.100 mm (floor 0.087)."""
    urdf = scene.urdf_file(tmp_path)
    q = scene.configurations(40)
    q[:, 5] = np.random.default_rng(5).uniform(-0.02, 0.02, 40)
    csv = scene.points_file(tmp_path / 'data', m=40, q=q)
    code, r, err = identify(capsys, csv, urdf, '--json')
    assert code == 0, err
    assert r['verdict'] == {'passed': True, 'problems': []}
    assert [h['name'] for h in r['held']] == ['x_wrist_3_joint']
    held = r['held'][0]
    assert 0.9e-3 < held['std'] < 1.1e-3
    assert held['reason'].startswith('the data do not determine it (+- 0.9')
    assert 'x_wrist_3_joint' not in {p['name'] for p in r['identified']}
    assert r['held_out']['nominal']['rmse_mm'] > 1.0
    assert r['held_out']['calibrated']['rmse_mm'] < 1.5 * FLOOR_MM
    assert all(f['held'] == 1 for f in r['folds'])         # every fold holds it too
    code, out, _ = identify(capsys, csv, urdf)
    assert code == 0 and 'held x_wrist_3_joint at nominal: the data do not determine it' in out
