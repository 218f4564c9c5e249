"""Write-back (issue 29 item 3): the calibrated model into each cell robot's own URDF, checked
with pinocchio (an independent URDF reader and FK), and the UR kinematics YAML round trip."""
from __future__ import annotations

from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np
from numpy.testing import assert_allclose
import pinocchio as pin
import pytest

from cobot_calib_ros.core.kinematics import fk, model_by_name
from cobot_calib_ros.core.kinematics.ur_description import (apply_ur_kinematics, is_ur,
                                                            parse_ur_kinematics, ur_kinematics,
                                                            ur_kinematics_yaml)
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf, rewrite_urdf

CELLS = Path(__file__).resolve().parents[3] / 'config' / 'cells'
# robot: (model, URDF file, base link, tip link); the URDFs are the cells' own descriptions
ROBOTS = {
    'sawyer': (lambda: model_by_name('sawyer'), 'sawyer.urdf', 'right_arm_base_link',
               'right_hand'),
    'iiwa7': (lambda: model_by_name('iiwa7'), 'iiwa7.urdf', 'lbr_link_0', 'lbr_link_ee'),
    'ur10e': (lambda: model_from_urdf((CELLS / 'ur10e.urdf').read_text(), 'base_link',
                                      'tool0', 'ur10e'), 'ur10e.urdf', 'base_link', 'tool0'),
}
LENGTHS = {'x', 'y', 'z', 'a', 'd'}
OFFSETS = {'yaw', 'theta'}          # turns about the joint axis (origin models: its yaw)


def realistic(model, rng) -> np.ndarray:
    """Nominal + deviations of a real arm: origins 0.1-0.5 mm, tilts 0.5-2 mrad, zero offsets
    ~1 mrad, random signs."""
    sign = rng.choice([-1.0, 1.0], model.nominal.size)
    dev = []
    for name in model.parameter_names:
        field = name.split('_')[0]
        if field in LENGTHS:
            dev.append(rng.uniform(1e-4, 5e-4))
        elif field in OFFSETS:
            dev.append(rng.normal(1e-3, 2e-4))
        else:
            dev.append(rng.uniform(5e-4, 2e-3))
    return model.nominal + sign * np.array(dev)


def within_limits(model, rng, m) -> np.ndarray:
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    return rng.uniform(lo, hi, (m, len(model.joint_names)))


def names(text: str, tag: str) -> list[str]:
    return sorted(e.get('name') for e in ET.fromstring(text).findall(tag))


def pinocchio_fk(text: str, joints, base: str, tip: str, q: np.ndarray) -> np.ndarray:
    """(m, 4, 4) pose of ``tip`` in ``base`` by pinocchio, q (m, n) for ``joints`` (the other
    joints at 0)."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    index = [model.joints[model.getJointId(name)].idx_q for name in joints]
    base_id, tip_id = (model.getFrameId(link, pin.FrameType.BODY) for link in (base, tip))
    assert base_id < model.nframes and tip_id < model.nframes
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(q):
        full = pin.neutral(model)
        full[index] = qk
        pin.framesForwardKinematics(model, data, full)
        out[k] = (data.oMf[base_id].inverse() * data.oMf[tip_id]).homogeneous
    return out


def urdf_joints(text: str, base: str, tip: str) -> list[str]:
    """The moving joints from base to tip, in order (as the rewrite matches them)."""
    parent = {e.find('child').get('link'): e for e in ET.fromstring(text).findall('joint')}
    out, link = [], tip
    while link != base:
        joint = parent[link]
        if joint.get('type') != 'fixed':
            out.append(joint.get('name'))
        link = joint.find('parent').get('link')
    return out[::-1]


@pytest.mark.parametrize('robot', sorted(ROBOTS))
def test_the_written_back_urdf_loads_in_pinocchio_with_the_identified_kinematics(robot):
    make, file, base, tip = ROBOTS[robot]
    model, original = make(), (CELLS / file).read_text()
    rng = np.random.default_rng(29)
    params = realistic(model, rng)
    text = rewrite_urdf(original, model, params, base_link=base, tip_link=tip,
                        note='calibration test-1, 2026-11-27, test')
    assert '<!-- calibration test-1, 2026-11-27, test -->' in text
    for tag in ('link', 'joint'):
        assert names(text, tag) == names(original, tag)
    joints = urdf_joints(original, base, tip)
    nominal_pin, written = pin.buildModelFromXML(original), pin.buildModelFromXML(text)
    assert list(written.names) == list(nominal_pin.names)
    assert [f.name for f in written.frames] == [f.name for f in nominal_pin.frames]
    assert_allclose(written.upperPositionLimit, nominal_pin.upperPositionLimit, rtol=0, atol=0)

    q = within_limits(model, rng, 1000)
    # the tip link is the model's flange: at nominal the two descriptions agree
    assert_allclose(pinocchio_fk(original, joints, base, tip, q[:50]),
                    fk(model.chain(), q[:50]), rtol=0, atol=1e-9)
    T_pin, T_model = pinocchio_fk(text, joints, base, tip, q), fk(model.chain(params), q)
    assert np.abs(T_pin[:, :3, 3] - T_model[:, :3, 3]).max() <= 1e-9
    assert np.abs(T_pin[:, :3, :3] - T_model[:, :3, :3]).max() <= 1e-9
    # and the deviations matter: the nominal URDF is off by far more
    assert np.abs(pinocchio_fk(original, joints, base, tip, q[:50])[:, :3, 3]
                  - T_model[:50, :3, 3]).max() > 1e-4


@pytest.mark.parametrize('robot', sorted(ROBOTS))
def test_at_the_nominal_parameters_the_urdf_comes_back_unchanged(robot):
    make, file, base, tip = ROBOTS[robot]
    model, original = make(), (CELLS / file).read_text()
    text = rewrite_urdf(original, model, model.nominal, base_link=base, tip_link=tip)
    old, new = ET.fromstring(original), ET.fromstring(text)
    assert new.get('name') == old.get('name')
    for joint in old.findall('joint'):
        o, n = joint.find('origin'), new.find(f"joint[@name='{joint.get('name')}']/origin")
        for attribute in ('xyz', 'rpy'):
            assert_allclose(numbers(n, attribute), numbers(o, attribute), rtol=0, atol=1e-12)


def numbers(origin: ET.Element | None, attribute: str) -> list[float]:
    """An <origin> attribute's numbers, URDF's zeros when absent."""
    text = '0 0 0' if origin is None else origin.get(attribute, '0 0 0')
    return [float(v) for v in text.split()]


def test_a_dh_model_on_a_urdf_whose_frames_are_not_its_own_is_refused():
    """iiwa 14's MDH table on MUKCa's iiwa14.urdf: its A2/A4 axes are 0.436 mm off the MDH
    axes, so no fixed transform ties the link frames to the model's."""
    text = (CELLS.parent.parent / 'test' / 'data' / 'mukca-kuka-iiwa14' / 'iiwa14.urdf') \
        .read_text()
    model = model_by_name('iiwa14')
    with pytest.raises(ValueError, match="'joint_a2': its axis is not the nominal model joint"):
        rewrite_urdf(text, model, model.nominal, base_link='base_link')
    iiwa7 = model_by_name('iiwa7')
    with pytest.raises(ValueError, match='name the link at the end of its chain'):
        rewrite_urdf((CELLS / 'iiwa7.urdf').read_text(), iiwa7, iiwa7.nominal,
                     base_link='lbr_link_0')
    shifted = (CELLS / 'iiwa7.urdf').read_text().replace('xyz="0.0 0.0707 0.091"',
                                                         'xyz="0.0 0.0707 0.092"', 1)
    with pytest.raises(ValueError, match=r"tip_link 'lbr_link_ee' is 1 mm / 0 mrad from the "
                                         r"flange of model 'iiwa7'"):   # A7 1 mm up its axis
        rewrite_urdf(shifted, iiwa7, iiwa7.nominal, base_link='lbr_link_0',
                     tip_link='lbr_link_ee')
    with pytest.raises(ValueError, match=r"moving joints from 'lbr_link_0' to 'lbr_link_5'"):
        rewrite_urdf((CELLS / 'iiwa7.urdf').read_text(), iiwa7, iiwa7.nominal,
                     base_link='lbr_link_0', tip_link='lbr_link_5')


# --- UR kinematics YAML ------------------------------------------------------------------------

def test_the_ur_kinematics_yaml_round_trips_through_its_own_layout():
    make, file, base, tip = ROBOTS['ur10e']
    model, original = make(), (CELLS / file).read_text()
    assert is_ur(model.joint_names) and not is_ur(model_by_name('iiwa7').joint_names)
    params = realistic(model, np.random.default_rng(3))
    calibrated = rewrite_urdf(original, model, params, base_link=base)
    text = ur_kinematics_yaml(ur_kinematics(calibrated), 'cobot_calib_k1', 'calibration k1')
    assert text.startswith('# calibration k1\nkinematics:\n  shoulder:\n    x: ')
    origins, hash_ = parse_ur_kinematics(text)
    assert hash_ == 'cobot_calib_k1'
    assert list(origins) == ['shoulder', 'upper_arm', 'forearm', 'wrist_1', 'wrist_2', 'wrist_3']
    # what the UR description builds from the YAML is the calibrated chain
    rebuilt = model_from_urdf(apply_ur_kinematics(original, origins), base, tip, 'r')
    written = model_from_urdf(calibrated, base, tip, 'w')
    assert_allclose(rebuilt.chain().placements, written.chain().placements, rtol=0, atol=1e-12)
    q = within_limits(model, np.random.default_rng(4), 200)
    assert_allclose(fk(rebuilt.chain(), q), fk(model.chain(params), q), rtol=0, atol=1e-12)
    # the nominal YAML is the URDF's own numbers
    nominal, _ = parse_ur_kinematics(ur_kinematics_yaml(ur_kinematics(original), ''))
    assert nominal['shoulder'] == (0.0, 0.0, 0.1807, 0.0, 0.0, 0.0)
    assert nominal['forearm'][:3] == (-0.6127, 0.0, 0.0)


@pytest.mark.parametrize('text, words', [
    ('kinematics: 3', 'expected a top-level "kinematics:" mapping'),
    ('kinematics: {shoulder: {x: 0, y: 0, z: 0.1, roll: 0, pitch: 0, yaw: 0}}',
     'kinematics.upper_arm: expected {x, y, z, roll, pitch, yaw}'),
    ('kinematics: {shoulder: {x: 0, y: 0, z: .nan, roll: 0, pitch: 0, yaw: 0}}',
     'kinematics.shoulder.z: expected a finite number'),
    ('[', 'not YAML'),
])
def test_a_broken_ur_kinematics_yaml_names_the_key(text, words):
    with pytest.raises(ValueError, match=words.replace('{', r'\{').replace('}', r'\}')):
        parse_ur_kinematics(text, 'k.yaml')
