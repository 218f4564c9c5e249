"""loaders: the files the core used to read itself (issue 16 design 6), and a cell whose robot
is a URDF chain resolved by core.kinematics.robots.model_for (design 4: one robot resolver)."""
from pathlib import Path
import re
import shutil

import numpy as np
import pytest

from cobot_calib_ros.core.cell import CellFileError
from cobot_calib_ros.core.kinematics import fk, model_for, ROBOTS
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file, DEFAULT_CELL

IIWA14_URDF = Path(__file__).resolve().parent / 'data' / 'mukca-kuka-iiwa14' / 'iiwa14.urdf'
URDF_ROBOT = '  robot: {urdf: iiwa14.urdf, base_link: base_link, tip_link: tool0, name: iiwa14u}'


def _cell_with_robot(tmp_path: Path, robot_line: str) -> Path:
    text, count = re.subn(r'^  robot: \{model: sawyer\b.*$', robot_line,
                          cell_file(DEFAULT_CELL).read_text(), count=1, flags=re.M)
    assert count == 1
    path = tmp_path / 'urdf_cell.yaml'
    path.write_text(text)
    return path


def test_a_built_in_robot_resolves_by_name(tmp_path):
    bare = load_cell(_cell_with_robot(tmp_path, '  robot: sawyer'))
    assert bare.robot == 'sawyer' and bare.urdf_robot is None
    assert model_for(bare).name == 'sawyer' and 'sawyer' in ROBOTS


def test_a_built_in_model_with_its_description_keeps_the_built_in_kinematics(tmp_path):
    cell = load_cell(cell_file(DEFAULT_CELL))
    assert cell.robot == 'sawyer' and cell.urdf_robot.model == 'sawyer'
    assert model_for(cell).name == 'sawyer' and model_for(cell).kind == 'origin'
    assert '<joint name="right_j6"' in cell.urdf_robot.urdf          # its description
    iiwa = load_cell(cell_file('iiwa7_close'))           # a DH model, a URDF of other frames
    assert model_for(iiwa).kind == 'mdh' and iiwa.urdf_robot.base_link == 'lbr_link_0'
    with pytest.raises(CellFileError, match=r"cell.robot.model: unknown robot model 'ur3'"):
        load_cell(_cell_with_robot(tmp_path, '  robot: {model: ur3, urdf: sawyer.urdf, '
                                             'base_link: a, tip_link: b}'))


def test_a_urdf_robot_is_read_beside_the_cell_file_and_resolved(tmp_path):
    shutil.copy(IIWA14_URDF, tmp_path / 'iiwa14.urdf')
    cell = load_cell(_cell_with_robot(tmp_path, URDF_ROBOT))
    assert cell.robot == 'iiwa14u'
    assert cell.urdf_robot.base_link == 'base_link' and cell.urdf_robot.tip_link == 'tool0'
    model = model_for(cell)
    direct = model_from_urdf(IIWA14_URDF.read_text(), 'base_link', 'tool0', 'iiwa14u')
    assert model.name == 'iiwa14u' and len(model.joint_names) == 7
    q = np.random.default_rng(3).uniform(-1.0, 1.0, (5, 7))
    assert np.array_equal(fk(model.chain(), q), fk(direct.chain(), q))


def test_a_missing_urdf_names_the_file(tmp_path):
    with pytest.raises(CellFileError, match=r'cell.robot.urdf: cannot read .*iiwa14.urdf'):
        load_cell(_cell_with_robot(tmp_path, URDF_ROBOT))


def test_an_unknown_robot_names_the_built_in_ones_and_the_urdf_form(tmp_path):
    with pytest.raises(CellFileError, match=r"unknown robot 'ur5'.*iiwa7.*urdf: FILE"):
        load_cell(_cell_with_robot(tmp_path, '  robot: ur5'))
