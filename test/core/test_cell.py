"""The nominal cell file: what the user configures, and clear errors for files that do not fit."""
import shutil

import numpy as np
import pytest

from cobot_calib_ros.core.cell import CELL_KEYS, CellFileError, check_frame_id
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file

SAWYER = cell_file('sawyer_close')


def test_the_shipped_cells_load_with_their_layouts():
    cell = load_cell(SAWYER)
    assert (cell.robot, cell.layout, cell.layouts) == ('sawyer', 'close', ('close', 'wide'))
    assert cell.point_names == ['P1', 'P2', 'P3', 'P4', 'P5']
    np.testing.assert_allclose(cell.marker('P5').nominal_top, [0.25, 0.175, 0.02])
    assert load_cell(SAWYER, 'wide').marker('P1').xy == (0.0, 0.0)
    iiwa = load_cell(cell_file('iiwa7_close'))
    assert iiwa.robot == 'iiwa7' and len(iiwa.home) == 7


def _broken(tmp_path, old: str, new: str):
    text = SAWYER.read_text()
    assert old in text
    path = tmp_path / 'broken.yaml'
    path.write_text(text.replace(old, new, 1))
    shutil.copy(SAWYER.parent / 'sawyer.urdf', tmp_path)     # the robot's URDF, beside it
    return path


@pytest.mark.parametrize('old, new, words', [
    ('  robot: {model', '  robt: {model', ['broken.yaml:', 'cell.robt', 'unknown key',
                                             "did you mean 'robot'?"]),
    ('  robot: {model: sawyer, urdf: sawyer.urdf, base_link: right_arm_base_link, '
     'tip_link: right_hand}', '  robot: ur5', ['cell.robot', "unknown robot 'ur5'"]),
    ('  layout: close', '  layout: narrow', ['cell.layout', 'close, wide']),
    ('    xyz: [0.0, 0.0, 0.100]', '    xyz: [0.0, 0.1]', ['cell.T_flange_tool.xyz', '3 finite']),
    ('  user_frame: user_frame', "  user_frame: 'bad frame!'", ['cell.user_frame', 'tf2']),
    ('      P2: [0.35, 0.10]', '      P2: [0.35, x]', ['cell.layouts.close.P2']),
    ('cell:\n', 'cell: [\n', ['not valid YAML']),
])
def test_a_broken_cell_file_names_file_line_key_and_fix(tmp_path, old, new, words):
    with pytest.raises(CellFileError) as error:
        load_cell(_broken(tmp_path, old, new))
    for word in words:
        assert word in str(error.value)


@pytest.mark.parametrize('old, new, words', [
    ('  base_frame: base_link', '  base_frme: base_link',
     ['cell.base_frme', "unknown key 'base_frme'; did you mean 'base_frame'?"]),
    ('    rpy: [0.0, 0.0, 0.0]', '    rpz: [0.0, 0.0, 0.0]',
     ['cell.T_flange_tool.rpz', "did you mean 'rpy'?", 'known here: xyz, rpy']),
    ('    diameter: 0.0508', '    diametre: 0.0508', ["cell.spheres.diametre", "'diameter'"]),
    ('  camera: ', '  camra: ', ["unknown key 'camra'; did you mean 'camera'?"]),
])
def test_an_unknown_key_is_refused_with_the_nearest_known_one(tmp_path, old, new, words):
    """Issue 23.5: `base_frme` was ignored and the demo ran to the end with the default."""
    with pytest.raises(CellFileError) as error:
        load_cell(_broken(tmp_path, old, new))
    for word in words:
        assert word in str(error.value)


def test_every_key_of_the_shipped_cells_is_known():
    import yaml
    shipped = sorted(SAWYER.parent.glob('*.yaml'))
    assert len(shipped) >= 2
    for path in shipped:
        cell = yaml.safe_load(path.read_text())['cell']
        assert set(cell) <= set(CELL_KEYS), path
        load_cell(path)


@pytest.mark.parametrize('old, new, key, far', [
    ('      P1: [0.15, 0.10]', '      P1: [150, 100]', 'cell.layouts.close.P1', '150'),
    ('    xyz: [0.0, 0.0, 0.100]', '    xyz: [0.0, 0.0, 100.0]', 'cell.T_flange_tool.xyz', '100'),
    ('      S2: [0.300009, 0.0, 0.0]', '      S2: [300.009, 0.0, 0.0]',
     'cell.spheres.centres.S2', '300.009'),
    ('      1: [0.42, 0.175, 0.35]', '      1: [420, 175, 0.35]', 'cell.landmarks.markers.1',
     '420'),
])
def test_lengths_beyond_any_cell_are_refused_as_millimetres(tmp_path, old, new, key, far):
    """Issue 23.5: a layout in mm started the demo, which failed with 'no inverse kinematics
    solution ... position error 180 m'."""
    with pytest.raises(CellFileError) as error:
        load_cell(_broken(tmp_path, old, new))
    message = str(error.value)
    assert f'{key}: ' in message and f'is {far} m from the origin' in message
    assert 'lengths are in metres' in message


def test_the_error_gives_the_line_of_the_bad_key(tmp_path):
    path = _broken(tmp_path, '  layout: close', '  layout: narrow')
    line = 1 + next(i for i, t in enumerate(path.read_text().splitlines())
                    if t.startswith('  layout: narrow'))
    with pytest.raises(CellFileError, match=f'broken.yaml:{line}: cell.layout'):
        load_cell(path)


def test_a_missing_file_says_where_cells_are(tmp_path):
    with pytest.raises(CellFileError, match='config/cells'):
        load_cell(tmp_path / 'nope.yaml')


@pytest.mark.parametrize('frame_id, ok', [
    ('user_frame', True), ('table_2/user', True), ('bad frame!', False), ('', False),
    ('/user_frame', False)])
def test_frame_ids_are_checked_as_tf2_accepts_them(frame_id, ok):
    assert (check_frame_id(frame_id) is None) == ok


# the keys before issue 39.3 (one name per transform): each line names an old key
OLD_KEYS = [('  T_flange_tool:', '  tool_offset:'),                 # legacy name
            ('    T_flange_coupling:', '    coupling_offset:'),     # legacy name
            ('    T_flange_optical:', '    hand_eye:'),             # legacy name
            ('  T_flange_tool_true:', '  tool_offset_true:'),       # legacy name
            ('    p_flange_coupling_true:', '    coupling_offset_true:'),  # legacy name
            ('    T_flange_optical_true:', '    hand_eye_true:')]   # legacy name


def _with_old_keys(tmp_path):
    path = SAWYER
    for new, old in OLD_KEYS:
        path = _broken(tmp_path, new, old) if path == SAWYER else _rewritten(path, new, old)
    return path


def _rewritten(path, old: str, new: str):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return path


def test_a_cell_file_with_the_old_key_names_reads_the_same_with_a_note(tmp_path):
    from cobot_calib_ros.sim.scenario import load_simulation
    now = load_simulation(SAWYER)
    with pytest.warns(FutureWarning) as notes:
        before = load_simulation(_with_old_keys(tmp_path))
    said = ' '.join(str(n.message) for n in notes)
    for words in ('cell.tool_offset is now called T_flange_tool',                   # legacy name
                  'cell.spheres.coupling_offset is now called T_flange_coupling',   # legacy name
                  'simulation.tool_offset_true is now called T_flange_tool_true',   # legacy name
                  'broken.yaml:16:'):
        assert words in said
    assert not np.allclose(now.T_flange_tool_true, now.cell.T_flange_tool)   # the truth read
    for got, want in ((before.cell.T_flange_tool, now.cell.T_flange_tool),
                      (before.cell.spheres.T_flange_coupling, now.cell.spheres.T_flange_coupling),
                      (before.cell.camera.T_flange_optical, now.cell.camera.T_flange_optical),
                      (before.T_flange_tool_true, now.T_flange_tool_true),
                      (before.spheres.T_flange_coupling, now.spheres.T_flange_coupling),
                      (before.camera.T_flange_optical, now.camera.T_flange_optical)):
        np.testing.assert_array_equal(got, want)


def test_a_key_given_under_its_old_and_new_name_is_refused(tmp_path):
    old = '  tool_offset: {xyz: [0, 0, 0.1], rpy: [0, 0, 0]}\n'      # legacy name
    both = _broken(tmp_path, '  T_flange_tool:', old + '  T_flange_tool:')
    refusal = "cell.tool_offset: give 'T_flange_tool' only"          # legacy name
    with pytest.raises(CellFileError, match=refusal):
        load_cell(both)


def test_a_simulation_without_a_true_coupling_takes_the_nominal_one(tmp_path):
    from cobot_calib_ros.sim.scenario import load_simulation
    sim = load_simulation(_broken(tmp_path, '    p_flange_coupling_true: [0.0204, -0.0003, 0.1006]',
                                  ''))
    np.testing.assert_array_equal(sim.spheres.T_flange_coupling, sim.cell.spheres.T_flange_coupling)
