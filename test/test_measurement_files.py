"""Measurement files (CSV + YAML sidecar) and `identify --measurement`: units, markers per
sample, and bad data refused in one line naming the problem."""
from __future__ import annotations

import argparse
from pathlib import Path
import shutil

import numpy as np
import pytest

from cobot_calib_ros.cli import identify
from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_USAGE
from cobot_calib_ros.loaders.measurements import load_measurements

DATA = Path(__file__).resolve().parent / 'data'
UR10E = DATA / 'figaroh-ur10e'


def write(tmp_path: Path, csv: str, sidecar: str, name: str = 'm') -> Path:
    (tmp_path / f'{name}.csv').write_text(csv)
    (tmp_path / f'{name}.yaml').write_text(sidecar)
    return tmp_path / f'{name}.csv'


def test_pose_file_in_mm_and_degrees_with_quaternions(tmp_path):
    path = write(tmp_path, 'a,b,x,y,z,qw,qx,qy,qz\n90,-45,100,200,300,0.7071067811865476,0,0,'
                 '0.7071067811865476\n', '''
measurement: pose
units: {length: mm, angle: deg}
joints: [b, a]
position: [x, y, z]
rotation: [qw, qx, qy, qz]
rotation_format: quaternion_wxyz
''')
    f = load_measurements(path)
    np.testing.assert_allclose(f.measurements.q, [[-np.pi / 4, np.pi / 2]])
    T = f.measurements.values[0]
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert f.in_joint_order(('a', 'b')).measurements.q[0, 0] == pytest.approx(np.pi / 2)


def test_points_with_an_unseen_marker_become_one_row_per_seen_marker(tmp_path):
    path = write(tmp_path, 'j1,x1,y1,z1,x2,y2,z2,session\n0.1,1,2,3,4,5,6,am\n'
                 '0.2,1,2,3,,,,pm\n', '''
measurement: points
joints: [j1]
markers: {m1: [x1, y1, z1], m2: [x2, y2, z2]}
''')
    f = load_measurements(path)
    assert f.sample.tolist() == [0, 0, 1] and f.samples == 2
    assert f.measurements.target.tolist() == [0, 1, 0]
    np.testing.assert_allclose(f.measurements.q[:, 0], [0.1, 0.1, 0.2])
    assert f.groups('session').tolist() == ['am', 'am', 'pm']


@pytest.mark.parametrize('csv, sidecar, message', [
    ('a,x,y\n1,2,3\n', 'measurement: points\njoints: [a]\nmarkers: {m: [x, y, z]}\n',
     r"m\.csv: missing columns \['z'\] \(marker m\)"),
    ('a,x,y,z\n1,2,3,oops\n', 'measurement: points\njoints: [a]\nmarkers: {m: [x, y, z]}\n',
     r"line 2, column 'z': 'oops' is not a number"),
    ('a,x\n1,2\n', 'measurement: laser\n', r'"measurement" must be one of'),
    ('a,x\n1,2,3\n', 'measurement: pose\n', r'lines \[2\] do not have 2 fields'),
    ('a,s\n1,0\n', 'measurement: spheres\njoints: [a]\n', r'"sphere" must name the column'),
])
def test_bad_files_are_refused_in_one_line(tmp_path, csv, sidecar, message):
    path = write(tmp_path, csv, sidecar)
    with pytest.raises(ValueError, match=message) as e:
        load_measurements(path)
    assert '\n' not in str(e.value)


def test_a_csv_without_its_sidecar_is_refused(tmp_path):
    (tmp_path / 'm.csv').write_text('a\n1\n')
    with pytest.raises(ValueError, match=r'm\.yaml: cannot read the sidecar of m\.csv'):
        load_measurements(tmp_path / 'm.csv')


def args(**given) -> argparse.Namespace:
    defaults = dict(urdf=str(UR10E / 'robot.urdf'), base_link=None, tip_link=None, dh=None,
                    source=str(UR10E / 'calibration.csv'), measurement='pose', model=None,
                    folds=None, leave_out=None, json=True, ball=(0.0, 0.0, 0.04),
                    loss='soft_l1', max_deviation_mm=5.0, max_deviation_mrad=50.0,
                    cell=None, robot=None, solver='lm', max_configs=0, dry_run=False,
                    data_dir=None, db=None)
    defaults.update(given)
    return argparse.Namespace(**defaults)


def refusal(capsys, code: int = EXIT_USAGE, **given) -> str:
    assert identify.offline(args(**given)) == code
    out, err = capsys.readouterr()
    assert out == '' and err.count('\n') == 1
    return err


def test_a_urdf_without_the_named_link_is_refused(capsys):
    err = refusal(capsys, tip_link='gripper')
    assert "gripper" in err and 'robot.urdf' in err


def test_mdh_and_full_each_say_which_robot_description_they_need(capsys):
    """Issue 31.9: `--model mdh --urdf` was refused with "needs a model of kind 'mdh'" while
    the README listed mdh beside --urdf; the refusal now says what to give instead."""
    err = refusal(capsys, model='mdh')
    assert '--model mdh needs a DH table (--dh FILE)' in err and 'use --model full' in err
    err = refusal(capsys, model='full', urdf=None, dh=str(DATA / 'industrial-calibration-'
                                                           'positioner' / 'positioner_dh.yaml'))
    assert '--model full needs a URDF (--urdf FILE)' in err and 'use --model mdh' in err


def test_the_wrong_measurement_kind_is_refused(capsys):
    assert 'holds pose measurements, not points' in refusal(capsys, measurement='points')


def test_too_few_rows_for_the_parameters_are_refused(tmp_path, capsys):
    lines = (UR10E / 'calibration.csv').read_text().splitlines()
    (tmp_path / 'few.csv').write_text('\n'.join(lines[:6]) + '\n')
    shutil.copy(UR10E / 'calibration.yaml', tmp_path / 'few.yaml')
    err = refusal(capsys, EXIT_FAILED, source=str(tmp_path / 'few.csv'), folds=2)
    assert 'REFUSED: 5 rows give 30 equations for' in err and 'measure more rows' in err


def test_a_leave_out_column_that_is_not_there_is_refused(capsys):
    assert '--leave-out session: no such column' in refusal(capsys, leave_out='session')


def test_a_camera_on_the_arm_is_read_as_the_board_seen_from_it(tmp_path):
    """Noise-free T_camera_board with the camera on wrist_3_link and the board fixed in the
    cell, written in mm and degrees with rotation vectors: identified held out to < 1e-6 mm."""
    from scipy.spatial.transform import Rotation
    from cobot_calib_ros.core.frames import from_vector, invert
    from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
    from cobot_calib_ros.core.kinematics.model import fk
    from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
    model = model_from_urdf((UR10E / 'robot.urdf').read_text(), 'base_link', 'wrist_3_link',
                            'ur10e')
    rng = np.random.default_rng(11)
    true = model.nominal + rng.normal(0.0, 1e-3, model.nominal.shape)
    q = rng.uniform(-2.5, 2.5, (24, 6))
    camera, board = from_vector([0.03, -0.05, 0.08, 0.1, 0.2, -1.0]), \
        from_vector([0.9, 0.2, -0.1, 3.0, 0.1, 0.2])
    seen = [invert(T @ camera) @ board for T in fk(model.chain(true), q)]
    rows = ['a,b,c,d,e,f,x,y,z,rx,ry,rz']
    for qi, T in zip(q, seen):
        rv = np.degrees(Rotation.from_matrix(T[:3, :3]).as_rotvec())
        rows.append(','.join(repr(float(v)) for v in [*np.degrees(qi), *(T[:3, 3] * 1e3), *rv]))
    path = write(tmp_path, '\n'.join(rows) + '\n', '''
measurement: pose
units: {length: mm, angle: deg}
joints: [a, b, c, d, e, f]
position: [x, y, z]
rotation: [rx, ry, rz]
rotation_format: rotvec
camera: on_arm
''')
    data = load_measurements(path).measurements
    cv = mf.cross_validate(mf.ErrorModel(model, 'full'), data, mf.kfold(len(data), 3))
    assert cv.nominal['max_mm'] > 0.5
    assert cv.calibrated['max_mm'] < 1e-6 and cv.calibrated['rot_rms_mrad'] < 1e-6


def test_the_command_line_reaches_the_measurement_path(capsys):
    """`cobot-calib identify --urdf --tip-link --source --measurement --model --folds --json`
    through the real parser: the report's contract fields."""
    import json
    from cobot_calib_ros.cli.main import main
    assert main(['identify', '--urdf', str(UR10E / 'robot.urdf'), '--base-link', 'base_link',
                 '--tip-link', 'wrist_3_link', '--source', str(UR10E / 'calibration.csv'),
                 '--measurement', 'pose', '--model', 'offsets', '--folds', '3', '--loss',
                 'linear', '--json']) == EXIT_FAILED
    out, err = capsys.readouterr()
    report = json.loads(out)
    # 16 unknowns on 15 training rows per fold over-fit: held out worse than nominal
    assert not report['verdict']['passed'] and 'worse than nominal' in err
    assert report['stored'] is False and report['not_stored'] == ('refused by its gate: '
                                                                   'nothing stored')
    assert report['held_out']['calibrated']['rmse_mm'] > report['held_out']['nominal']['rmse_mm']
    assert report['validation'] == {'folds': 3} and report['model'] == 'offsets'
    assert set(report['held_out']['calibrated']) >= {'rmse_mm', 'mean_mm', 'max_mm',
                                                      'rot_rms_mrad'}
    assert (report['parameters_kept'], report['parameters_minimum']) == (4 + 12, 30)
    assert report['condition_number'] > 1.0
    assert [d['name'] for d in report['dropped']] == ['offset_shoulder_pan_joint',
                                                      'offset_wrist_3_joint']
