"""What a measurement file's identification is written back as (core writeback): joint offsets
folded into the placements give the same arm, a compliance is refused, UR joints with a
tf_prefix are a UR arm."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core.kinematics import fk
from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
from cobot_calib_ros.core.kinematics.identification.writeback import model_parameters, unseen
from cobot_calib_ros.core.kinematics.model import dh_model
from cobot_calib_ros.core.kinematics.ur_description import is_ur, ur_kinematics
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf

URDF = (Path(__file__).resolve().parents[2] / 'data' / 'plant-ur5e' / 'ur5e.urdf').read_text()
UR5E = model_from_urdf(URDF, 'base_link', 'tool0', 'ur5e', free_pitch=True)
Q = np.random.default_rng(2).uniform(-2.0, 2.0, (20, 6))


@pytest.mark.parametrize('model', [UR5E, dh_model(
    'dh6', tuple(f'j{i}' for i in range(6)),
    [[0.16, 0, 0, 1.5708], [0, 0, -0.42, 0], [0, 0, -0.39, 0], [0.13, 0, 0, 1.5708],
     [0.1, 0, 0, -1.5708], [0.1, 0, 0, 0]], [[-3, 3]] * 6)], ids=['urdf', 'dh'])
def test_joint_offsets_fold_into_the_placements(model):
    errors = mf.ErrorModel(model, 'offsets')
    names = errors.candidates
    values = np.random.default_rng(4).normal(0.0, 0.01, len(names))
    params = model_parameters(errors, names, values)
    assert_allclose(fk(model.chain(params), Q), errors.tip_poses(names, values, Q), rtol=0,
                    atol=1e-12)


def test_a_compliance_is_not_written_back():
    errors = mf.ErrorModel(UR5E, 'full+compliance')
    spring = [n for n in errors.candidates if n.startswith('compliance_')][0]
    with pytest.raises(ValueError, match=f'^{spring}: a joint compliance is not a URDF'):
        model_parameters(errors, (spring,), np.array([1e-4]))


def test_unseen_by_kind():
    dropped = [{'name': n, 'reason': 'r'} for n in ('x_shoulder_pan_joint', 'y_elbow_joint',
                                                    'yaw_wrist_3_joint')]
    assert [(u['name'], u['affects']) for u in unseen(UR5E, 'points', 1, dropped)] == [
        ('yaw_wrist_3_joint', 'tool')]
    assert unseen(UR5E, 'points', 3, dropped) == []           # three markers see the wrist
    assert [(u['name'], u['affects']) for u in unseen(UR5E, 'spheres', 1, dropped)] == [
        ('x_shoulder_pan_joint', 'base'), ('yaw_wrist_3_joint', 'tool')]


def test_ur_joints_with_a_tf_prefix_are_a_ur_arm():
    prefixed = URDF.replace('"shoulder_pan_joint"', '"left_shoulder_pan_joint"')
    for joint in ('shoulder_lift', 'elbow', 'wrist_1', 'wrist_2', 'wrist_3'):
        prefixed = prefixed.replace(f'"{joint}_joint"', f'"left_{joint}_joint"')
    names = [f'left_{j}' for j in UR5E.joint_names]
    assert is_ur(names) and is_ur(UR5E.joint_names)
    assert not is_ur(['left_' + UR5E.joint_names[0]] + list(UR5E.joint_names[1:]))
    assert ur_kinematics(prefixed, names) == ur_kinematics(URDF)
