"""What a stored kinematic calibration is written back as (issue 29 item 3): the cell's own URDF
with a comment naming the calibration, a UR arm's kinematics YAML, else the minimal chain."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.core.kinematics.ur_description import parse_ur_kinematics
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.kinematics import calibrated_descriptions
from cobot_calib_ros.store.records import KinematicInputs, KinematicRecord, KinematicResult


def record_of(model, params, record_id: str = 'k-20261127-101500') -> KinematicRecord:
    """A kinematic record of ``model`` at ``params`` (none of them identified: free empty)."""
    return KinematicRecord(
        id=record_id, stamp_ns=1_795_774_500_000_000_000, method='relative-lm',
        robot=model.name, inputs=KinematicInputs(source='collection-7'),
        result=KinematicResult(parameter_names=list(model.parameter_names),
                               params=list(params), p_flange_tool=[0.02, 0.0, 0.1],
                               free=[], values=[]))


@pytest.mark.parametrize('cell_name, base, tip, files', [
    ('sawyer_close', 'right_arm_base_link', 'right_hand', {'urdf'}),
    ('iiwa7_close', 'lbr_link_0', 'lbr_link_ee', {'urdf'}),
    ('ur10e_close', 'base_link', 'tool0', {'urdf', 'ur_kinematics'}),
])
def test_a_cell_with_its_urdf_gets_its_own_urdf_back(cell_name, base, tip, files):
    cell = load_cell(cell_file(cell_name))
    model = model_for(cell)
    params = model.nominal + np.random.default_rng(1).normal(0, 3e-4, model.nominal.shape)
    texts = calibrated_descriptions(record_of(model, params), model, cell.urdf_robot)
    assert set(texts) == files
    root, own = ET.fromstring(texts['urdf']), ET.fromstring(cell.urdf_robot.urdf)
    assert root.get('name') == own.get('name')
    assert sorted(e.get('name') for e in root.findall('link')) == sorted(
        e.get('name') for e in own.findall('link'))
    assert ('<!-- calibrated by cobot_calib_ros: kinematic calibration k-20261127-101500 of '
            f'robot {model.name}, 2026-11-27 10:15:00 UTC, relative-lm from collection-7;'
            in texts['urdf'])
    written = model_from_urdf(texts['urdf'], base, tip, 'w')
    q = np.random.default_rng(2).uniform(-1.5, 1.5, (100, len(model.joint_names)))
    assert_allclose(fk(written.chain(), q), fk(model.chain(params), q), rtol=0, atol=1e-12)
    if 'ur_kinematics' in files:
        _, hash_ = parse_ur_kinematics(texts['ur_kinematics'])
        assert hash_ == 'cobot_calib_k-20261127-101500'


def test_a_cell_without_a_urdf_gets_the_minimal_chain():
    model = model_for(load_cell(cell_file('sawyer_close')))
    texts = calibrated_descriptions(record_of(model, model.nominal), model, None)
    assert set(texts) == {'urdf'}
    assert ET.fromstring(texts['urdf']).get('name') == 'sawyer_calibrated'
