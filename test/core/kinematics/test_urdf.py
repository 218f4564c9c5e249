"""URDF <-> KinematicModel: loading, frame conversion, calibrated URDF round trips, errors."""
from __future__ import annotations

import math
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core.kinematics import fk, model_by_name
from cobot_calib_ros.core.kinematics.urdf import (calibrated_urdf, model_from_urdf,
                                                  rpy_from_matrix)

DATA = Path(__file__).resolve().parents[2] / 'data'
MUKCA_URDF = DATA / 'mukca-kuka-iiwa14' / 'iiwa14.urdf'
SAWYER_XACRO = DATA / 'sawyer-description' / 'sawyer_base.urdf.xacro'
SAWYER_NEUTRAL = [0.0, -1.18, 0.0, 2.18, 0.0, 0.57, 3.3161]  # named_poses.yaml [rad]
XACRO = '{http://www.ros.org/wiki/xacro}'


# --- helpers (independent of the module under test) ----------------------------------------

def rot(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation about a unit axis (Rodrigues)."""
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def origin(xyz, rpy) -> np.ndarray:
    """(4, 4) URDF joint origin: Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll)."""
    T = np.eye(4)
    T[:3, :3] = rot([0, 0, 1], rpy[2]) @ rot([0, 1, 0], rpy[1]) @ rot([1, 0, 0], rpy[0])
    T[:3, 3] = xyz
    return T


def table_fk(joints, q) -> np.ndarray:
    """Plain FK of a joint table [(xyz, rpy, axis or None for fixed)], q for the moving ones."""
    T, k = np.eye(4), 0
    for xyz, rpy, axis in joints:
        T = T @ origin(xyz, rpy)
        if axis is not None:
            R = np.eye(4)
            R[:3, :3] = rot(axis, q[k])
            T, k = T @ R, k + 1
    return T


def table_urdf(joints, limits=(-3.0, 3.0), kinds=None) -> str:
    """URDF text l0 -> l1 -> ... from the same table."""
    lines = ['<robot name="t">'] + [f'<link name="l{i}"/>' for i in range(len(joints) + 1)]
    for i, (xyz, rpy, axis) in enumerate(joints):
        kind = 'fixed' if axis is None else (kinds or {}).get(i, 'revolute')
        body = (f'<origin xyz="{" ".join(map(repr, xyz))}" rpy="{" ".join(map(repr, rpy))}"/>'
                f'<parent link="l{i}"/><child link="l{i + 1}"/>')
        if axis is not None:
            body += f'<axis xyz="{" ".join(map(repr, axis))}"/>'
            if kind == 'revolute':
                body += f'<limit lower="{limits[0]}" upper="{limits[1]}" effort="1" velocity="1"/>'
        lines.append(f'<joint name="j{i}" type="{kind}">{body}</joint>')
    return '\n'.join(lines + ['</robot>'])


def expand_sawyer_xacro(text: str, gazebo: bool = False, pedestal: bool = True) -> str:
    """Resolve the only xacro used by sawyer_base.urdf.xacro: <xacro:arg>, <xacro:if/unless
    value="$(arg NAME)">."""
    args = {'gazebo': gazebo, 'pedestal': pedestal}

    def expand(element: ET.Element) -> None:
        children = []
        for child in list(element):
            if child.tag == XACRO + 'arg':
                continue
            if child.tag in (XACRO + 'if', XACRO + 'unless'):
                name = child.get('value').removeprefix('$(arg ').removesuffix(')')
                if args[name] == (child.tag == XACRO + 'if'):
                    expand(child)
                    children.extend(child)
                continue
            expand(child)
            children.append(child)
        element[:] = children

    root = ET.fromstring(text)
    expand(root)
    return ET.tostring(root, encoding='unicode')


def sawyer_urdf() -> str:
    return expand_sawyer_xacro(SAWYER_XACRO.read_text())


def random_q(model, rng, m):
    lo = np.where(np.isfinite(model.lower), model.lower, -math.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, math.pi)
    return rng.uniform(lo, hi, (m, len(model.joint_names)))


def assert_same_fk(T_a, T_b, atol=1e-12):
    assert_allclose(T_a[..., :3, 3], T_b[..., :3, 3], rtol=0, atol=atol)
    assert_allclose(T_a[..., :3, :3], T_b[..., :3, :3], rtol=0, atol=atol)


def tool(xyz) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = xyz
    return T


# --- rpy ------------------------------------------------------------------------------------

@pytest.mark.parametrize('pitch', [0.3, -1.2, math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9,
                                   -math.pi / 2 + 1e-12, math.pi / 2 + 1e-7, 3.0])
def test_rpy_from_matrix_reconstructs_even_at_gimbal_lock(pitch):
    for roll, yaw in [(0.4, -2.0), (-3.1, 1.0), (0.0, 0.0), (math.pi, -math.pi)]:
        R = origin([0, 0, 0], [roll, pitch, yaw])[:3, :3]
        r, p, y = rpy_from_matrix(R)
        assert -math.pi / 2 <= p <= math.pi / 2
        assert_allclose(origin([0, 0, 0], [r, p, y])[:3, :3], R, rtol=0, atol=2e-15)


# --- MDH model -> minimal URDF -> model ----------------------------------------------------

@pytest.mark.parametrize('name', ['iiwa7', 'ur10'])
def test_mdh_round_trip_through_minimal_urdf(name):
    model = model_by_name(name)
    rng = np.random.default_rng(3)
    q = random_q(model, rng, 50)
    for params in (model.nominal, model.nominal + rng.normal(0, 0.01, model.nominal.shape)):
        ball = [0.001, -0.002, 0.04]
        text = calibrated_urdf(model, params, ball, robot_name=f'{name}_calibrated')
        loaded = model_from_urdf(text, 'base_link', 'tool0', 'loaded')
        assert loaded.kind == 'origin' and loaded.joint_names == model.joint_names
        assert_allclose(loaded.lower, model.lower)
        assert_allclose(loaded.upper, model.upper)
        assert_same_fk(fk(loaded.chain(), q), fk(model.chain(params, tool(ball)), q))
        root = ET.fromstring(text)
        assert root.get('name') == f'{name}_calibrated'
        assert {j.find('axis').get('xyz') for j in root.iter('joint')
                if j.get('type') == 'revolute'} == {'0 0 1'}


def test_minimal_urdf_near_gimbal_lock_and_continuous_joints():
    joints = [([0.1, 0.0, 0.2], [0.3, math.pi / 2 - 1e-10, -0.7], [0, 0, 1]),
              ([0.0, 0.2, 0.1], [1.0, -math.pi / 2, 2.0], [0, 0, 1]),
              ([0.0, 0.0, 0.1], [0.0, 0.0, 0.0], None)]
    model = model_from_urdf(table_urdf(joints, kinds={0: 'continuous'}), 'l0', 'l3', 't')
    assert model.lower[0] == -math.inf and model.upper[0] == math.inf
    text = calibrated_urdf(model, model.nominal, robot_name='t2', base_link='b', tool_link='e')
    assert ET.fromstring(text).find("joint[@name='j0']").get('type') == 'continuous'
    loaded = model_from_urdf(text, 'b', 'e', 't2')
    q = random_q(model, np.random.default_rng(0), 20)
    assert_same_fk(fk(loaded.chain(), q), fk(model.chain(), q))
    assert_same_fk(fk(model.chain(), q), np.stack([table_fk(joints, qi) for qi in q]))


# --- frame conversion: non-z axes and fixed joints ------------------------------------------

def test_axes_and_fixed_joints_are_folded_exactly():
    s = 1 / math.sqrt(2)
    joints = [([0, 0, 0.05], [0, 0, 0.2], None),
              ([0.01, 0.02, 0.3], [0.1, 0.2, 0.3], [0, 1, 0]),
              ([0, 0, 0.1], [0, 0, 0], None),
              ([0, -0.1, 0.2], [0, 0, 0], [-1, 0, 0]),
              ([0.1, 0, 0], [0, 0, 0], [0, 0, -1]),
              ([0, 0, 0.2], [0.5, -0.4, 1.0], [s, s, 0]),
              ([0, 0, 0.0], [0, 0, 0], [0, 0, 2.0]),  # unnormalised +z
              ([0, 0, 0.1], [0, 0, 0], None),
              ([0.0, 0.01, 0.02], [0, math.pi / 2, 0], None)]
    model = model_from_urdf(table_urdf(joints), 'l0', 'l9', 't')
    assert model.joint_names == ('j1', 'j3', 'j4', 'j5', 'j6')
    q = np.random.default_rng(1).uniform(-3, 3, (30, 5))
    assert_same_fk(fk(model.chain(), q), np.stack([table_fk(joints, qi) for qi in q]))
    # a sub-chain ending on a moving joint's child (axis -x): the flange only turns the
    # model frame back onto the link frame
    sub = model_from_urdf(table_urdf(joints), 'l2', 'l4', 'sub')
    assert sub.joint_names == ('j3',) and np.array_equal(sub.flange[:3, 3], [0, 0, 0])
    assert_allclose(sub.flange[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-16)
    assert_same_fk(fk(sub.chain(), q[:, :1]),
                   np.stack([table_fk(joints[2:4], qi) for qi in q[:, :1]]))


# --- Sawyer: the URDF joint origins are those of model_by_name('sawyer') ----------------------

def test_sawyer_urdf_gives_the_built_in_sawyer_model():
    loaded = model_from_urdf(sawyer_urdf(), 'right_arm_base_link', 'right_hand', 'sawyer')
    built_in = model_by_name('sawyer')
    assert loaded.joint_names == built_in.joint_names
    assert loaded.parameter_names == built_in.parameter_names
    assert np.array_equal(loaded.nominal, built_in.nominal)  # literal xyz/rpy
    assert np.array_equal(loaded.lower, built_in.lower)
    assert np.array_equal(loaded.upper, built_in.upper)  # non-gazebo +-4.7124 on right_j6
    assert_allclose(loaded.flange, built_in.flange, rtol=0, atol=1e-15)
    # From the pedestal 'base': the identity fixed mount folds away.
    from_base = model_from_urdf(sawyer_urdf(), 'base', 'right_hand', 'sawyer')
    assert np.array_equal(from_base.nominal, built_in.nominal)


@pytest.mark.parametrize('q, expected', [
    ([0.0] * 7, [1.0155, 0.1603, 0.3170]),
    (SAWYER_NEUTRAL, [0.4496, 0.1603, 0.21575]),
    ([0.3, -0.5, 0.2, 1.0, -0.4, 0.6, 1.0], [0.72185, 0.45363, 0.15185]),
])
def test_sawyer_urdf_fk_matches_the_robot_descriptions_cross_check(q, expected):
    model = model_from_urdf(sawyer_urdf(), 'right_arm_base_link', 'right_hand', 'sawyer')
    assert_allclose(fk(model.chain(), q)[:3, 3], expected, rtol=0, atol=6e-5)


def test_sawyer_calibrated_urdf_rewrites_only_the_arm_joint_origins():
    original = sawyer_urdf()
    model = model_by_name('sawyer')
    rng = np.random.default_rng(7)
    params = model.nominal + rng.normal(0, 0.002, model.nominal.shape)
    ball = [0.0, 0.01, 0.12]
    text = calibrated_urdf(model, params, ball, robot_name='sawyer_cal',
                           base_link='right_arm_base_link', tool_link='probe',
                           original_text=original)
    q = random_q(model, rng, 40)
    loaded = model_from_urdf(text, 'right_arm_base_link', 'probe', 'x')
    assert_same_fk(fk(loaded.chain(), q), fk(model.chain(params, tool(ball)), q))
    # the origins are the parameters, literally
    rows = model.rows(params)
    root = ET.fromstring(text)
    for name, row in zip(model.joint_names, rows):
        o = root.find(f"joint[@name='{name}']/origin")
        assert np.array_equal([float(v) for v in o.get('xyz').split()], row[:3])
        assert np.array_equal([float(v) for v in o.get('rpy').split()], row[3:])
    # everything else is kept
    old = ET.fromstring(original)
    assert len(root.findall('.//mesh')) == len(old.findall('.//mesh')) > 0
    for name in ('right_hand', 'right_hand_camera', 'head_pan', 'right_torso_itb'):
        assert (ET.tostring(root.find(f"joint[@name='{name}']"))
                == ET.tostring(old.find(f"joint[@name='{name}']")))
    # from 'base' with the nominal parameters: the arm FK is unchanged
    same = calibrated_urdf(model, model.nominal, robot_name='s', base_link='base',
                           original_text=original, tool_link='right_hand_camera2')
    again = model_from_urdf(same, 'base', 'right_hand', 'y')
    assert np.array_equal(again.nominal, model.nominal)


# --- MUKCa iiwa14.urdf -----------------------------------------------------------------------

# iiwa14.urdf (MUKCa), joint origins xyz [m] (rpy all 0) and axes; fixed tool0, ball_joint.
IIWA14_TABLE = [
    ([0, 0, 0], [0, 0, 0], [0, 0, 1]),
    ([-0.00043624, 0, 0.36], [0, 0, 0], [0, 1, 0]),
    ([0, 0, 0], [0, 0, 0], [0, 0, 1]),
    ([0.00043624, 0, 0.42], [0, 0, 0], [0, -1, 0]),
    ([0, 0, 0], [0, 0, 0], [0, 0, 1]),
    ([0, 0, 0.4], [0, 0, 0], [0, 1, 0]),
    ([0, 0, 0], [0, 0, 0], [0, 0, 1]),
    ([0, 0, 0.126], [0, 0, 0], None),   # joint_a7-tool0
    ([0, 0, 0.04], [0, 0, 0], None),    # ball_joint
]


def test_mukca_iiwa14_urdf_fk_matches_plain_numpy():
    text = MUKCA_URDF.read_text()
    model = model_from_urdf(text, 'base_link', 'tool0', 'iiwa14')
    ball = model_from_urdf(text, 'base_link', 'ball_link', 'iiwa14')
    assert model.joint_names == tuple(f'joint_a{i}' for i in range(1, 8))
    assert_allclose(model.upper, [2.9668, 2.0942, 2.9668, 2.0942, 2.9668, 2.0942, 3.0541])
    assert_allclose(model.lower, -model.upper)
    assert_same_fk(fk(ball.chain(), np.zeros(7)), table_fk(IIWA14_TABLE, np.zeros(7)))
    assert_allclose(fk(ball.chain(), np.zeros(7))[:3, 3], [0, 0, 1.346], atol=1e-15)
    q = random_q(model, np.random.default_rng(5), 50)
    assert_same_fk(fk(model.chain(), q), np.stack([table_fk(IIWA14_TABLE[:8], qi) for qi in q]))
    assert_same_fk(fk(ball.chain(), q), np.stack([table_fk(IIWA14_TABLE, qi) for qi in q]))
    assert_same_fk(fk(model.chain(tool=tool([0, 0, 0.04])), q), fk(ball.chain(), q))


def test_mukca_iiwa14_urdf_and_the_mdh_iiwa14_differ_only_by_the_a2_a4_offsets():
    """The URDF's +-0.436 mm x offsets on A2/A4 are absent from the MDH table."""
    urdf = model_from_urdf(MUKCA_URDF.read_text(), 'base_link', 'tool0', 'iiwa14')
    mdh = model_by_name('iiwa14')
    q = random_q(mdh, np.random.default_rng(2), 200)
    T_u, T_m = fk(urdf.chain(), q), fk(mdh.chain(), q)
    assert_allclose(T_u[:, :3, :3], T_m[:, :3, :3], rtol=0, atol=1e-12)
    gap = np.linalg.norm(T_u[:, :3, 3] - T_m[:, :3, 3], axis=1)
    assert 0 < gap.max() <= 2 * 0.00043624 + 1e-12
    no_offsets = MUKCA_URDF.read_text().replace('-0.00043624 0 0.36', '0 0 0.36').replace(
        '0.00043624 0 0.42', '0 0 0.42')
    plain = model_from_urdf(no_offsets, 'base_link', 'tool0', 'iiwa14')
    assert_same_fk(fk(plain.chain(), q), T_m)


def test_mukca_iiwa14_calibrated_urdf_rewrites_converted_joints():
    text = MUKCA_URDF.read_text()
    model = model_from_urdf(text, 'base_link', 'tool0', 'iiwa14')
    rng = np.random.default_rng(11)
    q = random_q(model, rng, 40)
    # nominal: the origins come back as they were
    same = ET.fromstring(calibrated_urdf(model, model.nominal, [0, 0, 0.04], robot_name='k',
                                         original_text=text, tool_link='ball_link'))
    old = ET.fromstring(text)
    for joint in old.iter('joint'):
        new = same.find(f"joint[@name='{joint.get('name')}']")
        for attribute in ('xyz', 'rpy'):
            a = [float(v) for v in joint.find('origin').get(attribute).split()]
            b = [float(v) for v in new.find('origin').get(attribute).split()]
            assert_allclose(b, a, rtol=0, atol=1e-15)
        if joint.find('axis') is not None:
            assert new.find('axis').get('xyz') == joint.find('axis').get('xyz')
    # perturbed, ball rewritten in place
    params = model.nominal + rng.normal(0, 0.003, model.nominal.shape)
    ball = [-0.0001, -0.0002, 0.0406]
    text2 = calibrated_urdf(model, params, ball, robot_name='k', original_text=text,
                            tool_link='ball_link')
    loaded = model_from_urdf(text2, 'base_link', 'ball_link', 'k')
    assert_same_fk(fk(loaded.chain(), q), fk(model.chain(params, tool(ball)), q))
    assert ET.fromstring(text2).find("joint[@name='joint_a2']/axis").get('xyz') == '0 1 0'
    assert len(ET.fromstring(text2).findall('joint')) == len(old.findall('joint'))
    # and the calibrated URDF's own model at tool0 agrees with the calibrated chain
    at_tool0 = model_from_urdf(text2, 'base_link', 'tool0', 'k')
    assert_same_fk(fk(at_tool0.chain(), q), fk(model.chain(params), q))


# --- errors -------------------------------------------------------------------------------------

def _mukca_with(old: str, new: str) -> str:
    text = MUKCA_URDF.read_text()
    assert old in text
    return text.replace(old, new, 1)


@pytest.mark.parametrize('text, base, tip, message', [
    ('<robot', 'a', 'b', 'well-formed'),
    ('<model name="x"/>', 'a', 'b', '<robot>'),
    (None, 'base_link', 'flange', "tip_link 'flange' is not a link"),
    (None, 'nowhere', 'tool0', "base_link 'nowhere' is not a link"),
    (None, 'tool0', 'link_3', "no serial path from 'tool0' down to 'link_3'"),
    (None, 'base', 'tool0', "no serial path from 'base'"),
    (None, 'link_7', 'tool0', "no moving joint between 'link_7' and 'tool0'"),
    (_mukca_with('<joint name="joint_a3" type="revolute">', '<joint name="joint_a3" '
                 'type="floating">'), 'base_link', 'tool0', "'joint_a3' has type 'floating'"),
    (_mukca_with('xyz="0 0 0.4"', 'xyz="0 0 0,4"'), 'base_link', 'tool0',
     r"joint 'joint_a6' <origin xyz=...>: expected 3 finite numbers"),
    (_mukca_with('xyz="0 0 0.126"', 'xyz="0 0 nan"'), 'base_link', 'tool0',
     "joint 'joint_a7-tool0'"),
    (_mukca_with('lower="-2.0942" upper="2.0942" velocity="1.4834"',
                 'lower="-2.0942" upper="${pi}" velocity="1.4834"'), 'base_link', 'tool0',
     "joint 'joint_a2' <limit> upper="),
    (_mukca_with('<limit effort="0" lower="-2.9668" upper="2.9668" velocity="1.7452"/>', ''),
     'base_link', 'tool0', "joint 'joint_a3': a revolute joint needs <limit"),
    (_mukca_with('<axis xyz="0 -1 0"/>', '<axis xyz="0 0 0"/>'), 'base_link', 'tool0',
     "joint 'joint_a4': <axis"),
    (_mukca_with('<child link="link_5"/>', '<child link="link_4"/>'), 'base_link', 'tool0',
     "link 'link_4' is the child of two joints"),
    ('<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:arg name="a" default="0"/>'
     '</robot>', 'a', 'b', 'xacro'),
])
def test_model_from_urdf_errors_name_the_problem(text, base, tip, message):
    with pytest.raises(ValueError, match=message):
        model_from_urdf(MUKCA_URDF.read_text() if text is None else text, base, tip, 'x')


def test_sawyer_xacro_unexpanded_is_refused():
    with pytest.raises(ValueError, match='expand it first'):
        model_from_urdf(SAWYER_XACRO.read_text(), 'right_arm_base_link', 'right_hand', 's')


def test_calibrated_urdf_errors():
    text = MUKCA_URDF.read_text()
    model = model_from_urdf(text, 'base_link', 'tool0', 'iiwa14')
    # the URDF's +-0.436 mm A2/A4 offsets: its link frames are not fixed to the MDH frames
    with pytest.raises(ValueError, match="'joint_a2': its axis is not the nominal model joint"):
        calibrated_urdf(model_by_name('iiwa14'), model_by_name('iiwa14').nominal,
                        robot_name='x', original_text=text)
    with pytest.raises(ValueError, match='expected'):
        calibrated_urdf(model, model.nominal[:-1], robot_name='x')
    with pytest.raises(ValueError, match='p_flange_tool'):
        calibrated_urdf(model, model.nominal, [0, 0], robot_name='x')
    with pytest.raises(ValueError, match="tool_link 'base' exists but is not attached"):
        calibrated_urdf(model, model.nominal, robot_name='x', original_text=text,
                        tool_link='base')
    with pytest.raises(ValueError, match="tool_link 'link_7' is the link of the last joint"):
        calibrated_urdf(model, model.nominal, robot_name='x', original_text=text,
                        tool_link='link_7')
    with pytest.raises(ValueError, match="'right_j1': its axis is not"):
        calibrated_urdf(model_by_name('sawyer'), model_by_name('sawyer').nominal,
                        robot_name='x', original_text=_sawyer_with_other_j1(),
                        base_link='right_arm_base_link')
    with pytest.raises(ValueError, match='not all in the URDF; name the link at the end'):
        calibrated_urdf(model_by_name('sawyer'), model_by_name('sawyer').nominal,
                        robot_name='x', original_text=text)
    with pytest.raises(ValueError, match='collide'):
        calibrated_urdf(model, model.nominal, robot_name='x', tool_link='link_1')


def _sawyer_with_other_j1() -> str:
    """The Sawyer URDF with its right_j1 origin changed: no longer the built-in model's."""
    return sawyer_urdf().replace('xyz="0.081 0.05 0.237"', 'xyz="0.08 0.05 0.237"')


def test_a_prismatic_joint_slides_along_its_axis():
    """joint_a3 made prismatic (axis z, limits in m): FK is the product of the origins with
    Tz(q3) there, the model marks it, pinocchio IK solves through it."""
    from cobot_calib_ros.core.kinematics import solve_ik
    text = _mukca_with('<joint name="joint_a3" type="revolute">',
                       '<joint name="joint_a3" type="prismatic">')
    model = model_from_urdf(text, 'base_link', 'tool0', 'slide')
    assert model.prismatic.tolist() == [False, False, True, False, False, False, False]
    plain = model_from_urdf(MUKCA_URDF.read_text(), 'base_link', 'tool0', 'iiwa14')
    q = np.array([0.3, -0.4, 0.0, 0.9, -0.2, 0.5, 0.1])
    slide = q.copy()
    slide[2] = 0.05                      # 5 cm along joint_a3's axis (local z)
    T_plain = fk(plain.chain(), q)
    axis = fk(model_from_urdf(MUKCA_URDF.read_text(), 'base_link', 'link_3', 'a3').chain(),
              q[:3])[:3, 2]
    expected = T_plain.copy()
    expected[:3, 3] += 0.05 * axis
    assert_allclose(fk(model.chain(), slide), expected, atol=1e-12)
    target = fk(model.chain(), slide)
    result = solve_ik(model.chain(), target, q)      # from q3 = 0: it has to slide
    assert result and result.q[2] > 0.01
    assert_allclose(fk(model.chain(), result.q), target, atol=1e-9)
