"""A plant's path with no suite and no simulation section (issue 37, must-show 1): a UR5e-like
arm with planted errors (plant_scene), its tracker CSV -> identify (stored, URDF + UR YAML
written, their paths in the JSON) -> a user frame from touched points -> filter a program in
that frame -> the controller's nominal inverse kinematics of the filtered targets, run on the
TRUE arm, lands within 2x the noise floor of each target (where the unfiltered program is
millimetres off)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.frames import from_pose
from cobot_calib_ros.core.kinematics import fk, solve_ik
from cobot_calib_ros.core.kinematics.ur_description import parse_ur_kinematics, ur_kinematics
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
from cobot_calib_ros.core.user_frame import fit_rigid
from cobot_calib_ros.store.cells import ResultsCell

import plant_scene as scene


@pytest.fixture(scope='module')
def plant(tmp_path_factory):
    folder = tmp_path_factory.mktemp('plant')
    return folder, scene.write(folder)


def run_json(capsys, argv) -> dict:
    code = main(argv + ['--json'])
    out = capsys.readouterr()
    assert code == 0, out.err
    return json.loads(out.out)


def on_the_true_arm(out: Path, T_base_user) -> tuple[list[float], list[float]]:
    """[m] per target of a filtered program ``out``: the true arm's probe tip from the
    controller's nominal inverse kinematics of the filtered pose, and of the unfiltered one,
    against the target on the true fixture. The controller holds the user frame as exported
    (``T_base_user``, the stored one) and solves the pose in it with its nominal model."""
    rows = [line.split(',') for line in out.read_text().splitlines()[1:]]
    nominal = scene.MODEL.chain(tool=scene.TOOL)
    errors, unfiltered = [], []
    for row, (name, T_user_tool) in zip(rows, scene.program_targets().items()):
        assert row[0] == name
        values, joints = np.array(row[1:8], dtype=float), np.array(row[8:], dtype=float)
        wanted = (scene.T_BASE_USER @ T_user_tool)[:3, 3]
        controller = solve_ik(nominal, T_base_user @ from_pose(values[:3], values[3:]), joints)
        assert controller, controller.message
        errors.append(np.linalg.norm(fk(scene.true_chain(), controller.q)[:3, 3] - wanted))
        naive = solve_ik(nominal, T_base_user @ T_user_tool, joints)
        unfiltered.append(np.linalg.norm(fk(scene.true_chain(), naive.q)[:3, 3] - wanted))
    return errors, unfiltered


def test_tracker_file_to_controller_on_the_true_arm(plant, capsys):
    folder, files = plant
    data = str(folder / 'results')
    report = run_json(capsys, ['identify', '--source', str(files['tracker']), '--urdf',
                               str(files['urdf']), '--cell', str(files['cell']),
                               '--data-dir', data])
    assert report['stored'] and report['active'] and report['verdict']['passed']
    figures = report['validation_max_mm']['held_out']
    assert figures['calibrated'] < 3 * scene.NOISE_RMS * 1e3 < figures['nominal']
    # the written URDF is the arm identified (every link and visual kept) ...
    urdf = Path(report['urdf_path']).read_text()
    assert report['calibration_id'] in urdf and 'not seen by the measurement' in urdf
    assert urdf.count('<visual>') == files['urdf'].read_text().count('<visual>') == 7
    written = model_from_urdf(urdf, 'base_link', 'tool0', 'ur5e')
    record = store.open(Path(data), None, ResultsCell('plant_ur5e', 'ur5e')).kinematics.get(
        report['calibration_id'])
    assert record['measured_through'] == {}
    q = scene.HOME + np.random.default_rng(5).uniform(-0.5, 0.5, (50, 6))
    identified = scene.MODEL.chain(np.array(record['result']['params']), tool=scene.TOOL)
    assert_allclose(fk(written.chain(tool=scene.TOOL), q), fk(identified, q), rtol=0,
                    atol=1e-12)
    # ... and the probe's tip of the truth within 4x the noise over the workspace, up to the
    # base's placement, which the tracker's registration takes (a touched frame cancels it);
    # one reflector sees the wrist's turn poorly (the correlated pairs in the report)
    registered = fit_rigid(fk(identified, q)[:, :3, 3], fk(scene.true_chain(), q)[:, :3, 3])
    assert registered.max_residual < 4 * scene.NOISE_RMS
    origins, hash_ = parse_ur_kinematics(Path(report['ur_kinematics_path']).read_text())
    assert origins == ur_kinematics(urdf) and report['calibration_id'] in hash_
    assert [u['name'] for u in report['unseen']] == [
        'y_wrist_3_joint', 'z_wrist_3_joint', 'pitch_wrist_3_joint', 'yaw_wrist_3_joint']

    frame = run_json(capsys, ['user-frame', '--points', str(files['points']), '--robot-cell',
                              str(files['cell']), '--data-dir', data])
    assert frame['active'] and frame['measured_through'] == {
        'kinematics': report['calibration_id'], 'tcp': 'nominal'}

    out = folder / 'filtered.csv'
    assert main(['filter', '--targets', str(files['program']), '--out', str(out), '--frame',
                 'user', '--robot-cell', str(files['cell']), '--data-dir', data]) == 0
    printed = capsys.readouterr()
    assert 'pitch_wrist_3_joint' in printed.err        # the tool it uses is affected
    errors, unfiltered = on_the_true_arm(out, np.array(frame['T_base_user']))
    assert max(errors) < 2 * scene.NOISE_RMS, np.array(errors) * 1e3
    assert min(unfiltered) > 20 * scene.NOISE_RMS      # the errors planted are seen without it


def test_a_dry_run_stores_nothing_and_says_so(plant, capsys):
    folder, files = plant
    data = folder / 'dry'
    report = run_json(capsys, ['identify', '--source', str(files['tracker']), '--urdf',
                               str(files['urdf']), '--no-store', '--data-dir', str(data)])
    assert report['stored'] is False and report['not_stored'] == '--no-store: a dry run'
    assert 'calibration_id' not in report and not data.exists()
    # the cell's URDF chain is the arm when no --urdf is given
    by_cell = run_json(capsys, ['identify', '--source', str(files['tracker']), '--cell',
                                str(files['cell']), '--no-store', '--data-dir', str(data)])
    assert by_cell['identified'] == report['identified'] and by_cell['robot'] == 'ur5e'


def test_without_a_cell_the_result_is_stored_under_the_arm(plant, capsys):
    folder, files = plant
    data = str(folder / 'by-arm')
    report = run_json(capsys, ['identify', '--source', str(files['tracker']), '--urdf',
                               str(files['urdf']), '--data-dir', data])
    again = run_json(capsys, ['identify', '--source', str(files['tracker']), '--urdf',
                              str(files['urdf']), '--data-dir', data])
    assert main(['history', '--data-dir', data, '--no-plots']) == 0     # two of one arm
    assert f'kinematics ur5e {again["calibration_id"]}' in capsys.readouterr().out
    active = store.open(Path(data), None, ResultsCell('ur5e', 'ur5e')).kinematics.active('ur5e')
    assert active['id'] == again['calibration_id']
    assert active['measured_through'] == {}
    assert_allclose(report['validation_max_mm']['held_out']['calibrated'],
                    report['held_out']['calibrated']['max_mm'])
    # no cell file at all: the URDF, its links, the probe and home on the command line
    robot = ['--urdf', str(files['urdf']), '--tip-link', 'tool0', '--t-flange-tool', '0', '0',
             '0.12', '0', '0', '0', '--data-dir', data]
    frame = run_json(capsys, ['user-frame', '--points', str(files['points']), *robot])
    assert frame['measured_through']['kinematics'] == again['calibration_id']
    out = folder / 'by-arm.csv'
    assert main(['filter', '--targets', str(files['program']), '--out', str(out), '--frame',
                 'user', '--home', *(str(v) for v in scene.HOME), *robot]) == 0
    assert max(on_the_true_arm(out, np.array(frame['T_base_user']))[0]) < 2 * scene.NOISE_RMS
    capsys.readouterr()
    assert main(['filter', '--targets', str(files['program']), '--out', str(out),
                 '--home', '0', *robot]) == 2
    assert capsys.readouterr().err.startswith('filter: --home: give 6 joint values [rad]')


def test_the_refusals_of_a_plant_path(plant, tmp_path, capsys):
    """A sidecar with more joints than the chain, a program in millimetres or out of reach, a
    touched point that does not fit: refused by name, nothing written or stored."""
    folder, files = plant
    data = str(tmp_path / 'results')
    sidecar = tmp_path / 'tracker.yaml'
    sidecar.write_text(files['sidecar'].read_text().replace('wrist_3_joint]',
                                                            'wrist_3_joint, x]'))
    (tmp_path / 'tracker.csv').write_text(files['tracker'].read_text())
    assert main(['identify', '--source', str(tmp_path / 'tracker.csv'), '--urdf',
                 str(files['urdf']), '--data-dir', data]) == 2
    assert "joint columns ['x'] are not joints of the chain ur5e" in capsys.readouterr().err
    assert not (tmp_path / 'results').exists()

    assert main(['identify', '--source', str(files['tracker']), '--urdf', str(files['urdf']),
                 '--cell', str(files['cell']), '--data-dir', data]) == 0
    capsys.readouterr()
    program = tmp_path / 'program.csv'
    program.write_text('name,x,y,z,qx,qy,qz,qw\nin_mm,350.0,130.0,470.0,1,0,0,0\n'
                       'far,3.0,0.0,0.4,1,0,0,0\n')
    out = tmp_path / 'out.csv'
    assert main(['filter', '--targets', str(program), '--out', str(out), '--robot-cell',
                 str(files['cell']), '--data-dir', data]) == 1
    err = capsys.readouterr().err
    assert 'target in_mm: cannot be reached by the calibrated model (' in err
    assert 'it looks like millimetres: give the position in metres' in err
    far = next(line for line in err.splitlines() if 'target far' in line)
    assert 'beyond the arm\'s reach of' in far and 'millimetres' not in far
    assert not out.exists()

    points = tmp_path / 'points.csv'
    header, *rows = files['points'].read_text().splitlines()
    rows[2] = rows[2].replace('F3,0.25,0.18,', 'F3,0.25,0.175,', 1)      # 5 mm off its drawing
    points.write_text('\n'.join([header, *rows]) + '\n')
    assert main(['user-frame', '--points', str(points), '--robot-cell', str(files['cell']),
                 '--data-dir', data]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f'user-frame {points}: REFUSED: ') and err.endswith(
        '; nothing stored\n')
    points.write_text('name,user_x,user_y\nF1,0,0\n')
    assert main(['user-frame', '--points', str(points), '--robot-cell', str(files['cell']),
                 '--data-dir', data]) == 2
    assert "missing columns ['user_z']" in capsys.readouterr().err


def test_a_cell_without_layouts_is_refused_by_name_where_they_are_needed(plant, capsys):
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.loaders import load_cell
    assert main(['up', '--cell', str(plant[1]['cell'])]) == 2
    assert capsys.readouterr().err.startswith(
        "up starts the mock robot, which needs the cell's simulation: section; ")
    assert main(['teach', '--cell', str(plant[1]['cell'])]) == 2
    assert "needs the cell's layouts: section, which cell 'plant_ur5e' has not" in \
        capsys.readouterr().err
    cell = load_cell(plant[1]['cell'])
    assert cell.markers == () and cell.spheres is None
    with pytest.raises(CellFileError, match=r"^a repeatability trial needs the cell's layouts: "
                                            r"section, which cell 'plant_ur5e' has not"):
        cell.require('a repeatability trial', 'layouts')


def test_the_walk_through_files_are_the_scene(plant):
    """test/data/plant-ur5e (the README's walk-through) is what plant_scene writes."""
    shipped = scene.URDF.parent
    for name, path in plant[1].items():
        mine = (shipped / path.name).read_text().splitlines()
        theirs = path.read_text().splitlines()
        assert len(mine) == len(theirs), name
        for a, b in zip(mine, theirs):
            cells = list(zip(a.split(','), b.split(',')))
            for x, y in cells:
                try:
                    assert float(x) == pytest.approx(float(y), rel=0, abs=1e-12), name
                except ValueError:
                    assert x == y, name


def test_a_user_frame_from_a_trackers_points_in_its_own_frame(plant, tmp_path, capsys):
    """Reference points measured by the tracker (in its frame, with the base's registration)
    give the true fixture within the noise, measured through no other result."""
    from cobot_calib_ros.core.frames import invert
    from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
    files = plant[1]
    T_base_tracker = invert(scene.T_TRACKER_BASE)
    rng = np.random.default_rng(11)
    lines = ['name,user_x,user_y,user_z,x,y,z']
    for name, p_user in scene.FIXTURE.items():
        p_base = scene.T_BASE_USER[:3, :3] @ np.array(p_user) + scene.T_BASE_USER[:3, 3]
        p = scene.T_TRACKER_BASE[:3, :3] @ p_base + scene.T_TRACKER_BASE[:3, 3] \
            + rng.normal(0.0, scene.NOISE_SD, 3)
        lines.append(','.join([name, *map(str, p_user), *(repr(float(v)) for v in p)]))
    points = tmp_path / 'tracker_points.csv'
    points.write_text('\n'.join(lines) + '\n')
    registration = [*T_base_tracker[:3, 3], *rpy_from_matrix(T_base_tracker[:3, :3])]
    frame = run_json(capsys, ['user-frame', '--points', str(points), '--robot-cell',
                              str(files['cell']), '--data-dir', str(tmp_path / 'results'),
                              '--base-from-tracker', *(repr(float(v)) for v in registration)])
    assert frame['active'] and frame['measured_through'] == {}
    assert_allclose(np.array(frame['T_base_user'])[:3, 3], scene.T_BASE_USER[:3, 3], rtol=0,
                    atol=2 * scene.NOISE_RMS)
    assert main(['user-frame', '--points', str(files['points']), '--robot-cell',
                 str(files['cell']), '--base-from-tracker', '0', '0', '0', '0', '0', '0']) == 2
    assert 'applies to measured x,y,z, not to joints' in capsys.readouterr().err
