"""The nominal cell file: what the user configures, and clear errors for files that do not fit."""
import numpy as np
import pytest

from cobot_calib_ros.core.cell import CellFileError, check_frame_id
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
    return path


@pytest.mark.parametrize('old, new, words', [
    ('  robot: sawyer ', '  robt: sawyer ', ['broken.yaml:', 'cell.robot', 'missing']),
    ('  robot: sawyer ', '  robot: ur5 ', ['cell.robot', "unknown robot 'ur5'"]),
    ('  layout: close', '  layout: narrow', ['cell.layout', 'close, wide']),
    ('    xyz: [0.0, 0.0, 0.100]', '    xyz: [0.0, 0.1]', ['cell.tool_offset.xyz', '3 finite']),
    ('  user_frame: user_frame', "  user_frame: 'bad frame!'", ['cell.user_frame', 'tf2']),
    ('      P2: [0.35, 0.10]', '      P2: [0.35, x]', ['cell.layouts.close.P2']),
    ('cell:\n', 'cell: [\n', ['not valid YAML']),
])
def test_a_broken_cell_file_names_file_line_key_and_fix(tmp_path, old, new, words):
    with pytest.raises(CellFileError) as error:
        load_cell(_broken(tmp_path, old, new))
    for word in words:
        assert word in str(error.value)


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
    assert (check_frame_id(frame_id) == '') == ok
