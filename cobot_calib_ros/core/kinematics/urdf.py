"""URDF <-> :class:`KinematicModel`: load a serial revolute chain, write a calibrated URDF.

:func:`model_from_urdf` turns the joints between two links of a URDF into a model of kind
``'origin'`` (x, y, z, roll, pitch, yaw per revolute joint, the URDF joint origin convention
``Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll)``, joint axis local z). Fixed joints are folded into the
next revolute joint's placement, or into ``flange`` after the last one. A revolute joint whose
axis is not +z gets a re-oriented model frame ``F' = F_urdf @ R_axis`` with ``R_axis @ z = axis``:
its placement and the next one absorb ``R_axis`` (the parameters are then those of the converted
placement, not the URDF's literal numbers). With ``free_pitch`` (identification's models), a
frame whose placement would have a pitch beyond 60 deg (near gimbal lock, where roll and yaw
turn about one axis and are one parameter) is also turned about its own axis, which frees the
pitch. FK is unchanged: ``fk(model.chain(), q)`` is the pose
of ``tip_link`` in ``base_link``.

:func:`rewrite_urdf` is the write-back: the robot's own URDF with only its chain's joint
origins changed to a calibrated model's (of either kind: a modified-DH model's frames are tied to
the URDF link frames by fixed transforms found at the nominal parameters). :func:`calibrated_urdf`
writes a URDF whose chain from ``base_link`` to ``tool_link`` reproduces
``fk(model.chain(params, Trans(p_flange_tool)), q)``: the rewrite plus a tool link, or a minimal
kinematic URDF when there is no original.

Only ``xml.etree``; lengths in metres, angles in radians.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import xml.etree.ElementTree as ET

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import from_xyz_rpy, invert, rotation_angle, skew
from cobot_calib_ros.core.kinematics.model import _model, KinematicModel

Array = NDArray[np.float64]

_MOVING = ('revolute', 'continuous', 'prismatic')
_XACRO_NS = 'http://www.ros.org/wiki/xacro'
GIMBAL_SIN = math.sin(math.radians(60.0))   # |pitch| beyond 60 deg: the frame is turned


# --- small geometry ----------------------------------------------------------------------

def rpy_from_matrix(R: ArrayLike) -> tuple[float, float, float]:
    """(roll, pitch, yaw) [rad] with Rz(yaw) Ry(pitch) Rx(roll) = R, exact near gimbal lock too.

    yaw = atan2(R10, R00) (0 when both vanish, pitch = +-pi/2); then M = Rz(-yaw) R has
    M10 = 0 by construction and is Ry(pitch) Rx(roll): pitch and roll come from M's first
    column and second row, both well conditioned for every pitch.
    """
    R = np.asarray(R, dtype=float)[:3, :3]
    if math.hypot(R[0, 0], R[1, 0]) < 1e-300:
        yaw = 0.0
    else:
        yaw = math.atan2(R[1, 0], R[0, 0])
    c, s = math.cos(yaw), math.sin(yaw)
    M = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    pitch = math.atan2(-M[2, 0], M[0, 0])
    roll = math.atan2(-M[1, 2], M[1, 1])
    return roll, pitch, yaw


def _axis_frame(axis: Array) -> Array:
    """(4, 4) rotation R with R @ z = axis (unit); identity for +z, exact for +-x/+-y/-z."""
    a = axis / np.linalg.norm(axis)
    R = np.eye(4)
    c = a[2]
    if c > 1.0 - 1e-15:
        return R
    if c < -1.0 + 1e-15:
        R[1, 1] = R[2, 2] = -1.0  # Rx(pi)
        return R
    V = skew([-a[1], a[0], 0.0])  # [z x a]x
    R[:3, :3] = np.eye(3) + V + V @ V / (1.0 + c)  # Rodrigues, rotation taking z onto a
    return R


def _fmt(values: ArrayLike) -> str:
    """Shortest round-trip decimal of each value; |v| < 1e-15 written as 0."""
    return ' '.join('0' if abs(v) < 1e-15 else repr(float(v)) for v in np.ravel(values))


# --- parsing -----------------------------------------------------------------------------

@dataclass
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, ...]
    rpy: tuple[float, ...]
    axis: Array
    lower: float
    upper: float
    element: ET.Element

    @property
    def origin(self) -> Array:
        return from_xyz_rpy(self.xyz, self.rpy)


@dataclass
class _Urdf:
    root: ET.Element
    links: set[str]
    joints: dict[str, _Joint]
    parent_joint: dict[str, _Joint]  # child link -> the joint above it


def _numbers(text: str | None, n: int, where: str, default: tuple[float, ...]
             ) -> tuple[float, ...]:
    """``n`` finite floats from a space-separated attribute; ValueError naming ``where``."""
    if text is None:
        return default
    parts = text.split()
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise ValueError(f'{where}: expected {n} finite numbers, got {text!r}; fix the URDF '
                         f'(numbers separated by spaces, no xacro expressions)')
    return values


def _number(element: ET.Element, attribute: str, where: str, default: float) -> float:
    return _numbers(element.get(attribute), 1, f'{where} {attribute}=', (default,))[0]


def _parse_root(text: str) -> ET.Element:
    try:
        root = ET.fromstring(text, parser=ET.XMLParser(
            target=ET.TreeBuilder(insert_comments=True)))
    except ET.ParseError as exc:
        raise ValueError(f'URDF is not well-formed XML: {exc}') from None
    if root.tag != 'robot':
        raise ValueError(f'URDF root element must be <robot>, got <{root.tag}>')
    for element in root.iter():
        if isinstance(element.tag, str) and element.tag.startswith('{' + _XACRO_NS + '}'):
            raise ValueError('text contains xacro elements; expand it first '
                             '(`xacro file.urdf.xacro > file.urdf`)')
    return root


def _parse(text: str) -> _Urdf:
    root = _parse_root(text)
    links: set[str] = set()
    for link in root.findall('link'):
        name = link.get('name')
        if not name:
            raise ValueError('a <link> has no name attribute')
        if name in links:
            raise ValueError(f'link {name!r} is declared twice')
        links.add(name)
    joints: dict[str, _Joint] = {}
    parent_joint: dict[str, _Joint] = {}
    for element in root.findall('joint'):
        joint = _parse_joint(element)
        if joint.name in joints:
            raise ValueError(f'joint {joint.name!r} is declared twice')
        if joint.child in parent_joint:
            raise ValueError(f'link {joint.child!r} is the child of two joints '
                             f'({parent_joint[joint.child].name!r}, {joint.name!r}): '
                             'a URDF must be a tree')
        joints[joint.name] = joint
        parent_joint[joint.child] = joint
    return _Urdf(root, links, joints, parent_joint)


def _parse_joint(element: ET.Element) -> _Joint:
    name = element.get('name')
    if not name:
        raise ValueError('a <joint> has no name attribute')
    where = f'joint {name!r}'
    kind = element.get('type')
    parent, child = element.find('parent'), element.find('child')
    if parent is None or child is None or not parent.get('link') or not child.get('link'):
        raise ValueError(f'{where}: needs <parent link="..."/> and <child link="..."/>')
    origin = element.find('origin')
    xyz = _numbers(None if origin is None else origin.get('xyz'), 3,
                   f'{where} <origin xyz=...>', (0.0, 0.0, 0.0))
    rpy = _numbers(None if origin is None else origin.get('rpy'), 3,
                   f'{where} <origin rpy=...>', (0.0, 0.0, 0.0))
    axis_element = element.find('axis')
    axis = np.array(_numbers(None if axis_element is None else axis_element.get('xyz'), 3,
                             f'{where} <axis xyz=...>', (1.0, 0.0, 0.0)))  # URDF default: x
    lower, upper = -math.inf, math.inf
    if kind in ('revolute', 'prismatic'):
        limit = element.find('limit')
        if limit is None:
            raise ValueError(f'{where}: a {kind} joint needs <limit lower=".." upper=".."/> '
                             '[rad or m] (or make a revolute one type="continuous")')
        lower = _number(limit, 'lower', f'{where} <limit>', 0.0)
        upper = _number(limit, 'upper', f'{where} <limit>', 0.0)
        if lower > upper:
            raise ValueError(f'{where}: <limit> lower {lower} > upper {upper}')
    if kind in _MOVING and not np.linalg.norm(axis) > 0.0:
        raise ValueError(f'{where}: <axis xyz="0 0 0"> has no direction')
    return _Joint(name, kind or '', parent.get('link'), child.get('link'), xyz, rpy, axis,
                  lower, upper, element)


def _path(urdf: _Urdf, base_link: str, tip_link: str) -> list[_Joint]:
    """Joints from base_link down to tip_link, in order; ValueError if there is no such path."""
    for role, link in (('base_link', base_link), ('tip_link', tip_link)):
        if link not in urdf.links:
            raise ValueError(f'{role} {link!r} is not a link of this URDF; its links: '
                             f'{sorted(urdf.links)}')
    path: list[_Joint] = []
    link, visited = tip_link, [tip_link]
    while link != base_link:
        joint = urdf.parent_joint.get(link)
        if joint is None or joint.parent in visited:
            raise ValueError(
                f'no serial path from {base_link!r} down to {tip_link!r}: going up from the tip '
                f'({" <- ".join(visited)}) never reaches {base_link!r}; choose a base_link '
                f'that is an ancestor of {tip_link!r}')
        path.append(joint)
        link = joint.parent
        visited.append(link)
    return path[::-1]


@dataclass
class _Serial:
    """A path split at its revolute joints (URDF frames, not yet axis-converted)."""

    moving: list[_Joint]
    before: list[Array]   # per moving joint: product of fixed joints since the previous one
    after: Array          # fixed joints after the last moving joint
    axes: list[Array]     # per moving joint: (4, 4) R_axis


def _serial(path: list[_Joint], base_link: str, tip_link: str,
            free_pitch: bool = False) -> _Serial:
    moving, before, axes = [], [], []
    acc = np.eye(4)
    for joint in path:
        if joint.type == 'fixed':
            acc = acc @ joint.origin
        elif joint.type in _MOVING:
            if joint.element.find('mimic') is not None:
                raise ValueError(f'joint {joint.name!r} mimics another joint; mimic joints are '
                                 'not supported in a calibration chain')
            moving.append(joint)
            before.append(acc)
            axes.append(_axis_frame(joint.axis))
            acc = np.eye(4)
        else:
            raise ValueError(f'joint {joint.name!r} has type {joint.type!r}; only revolute, '
                             'continuous, prismatic and fixed joints can be on the chain')
    if not moving:
        raise ValueError(f'no moving joint between {base_link!r} and {tip_link!r}')
    if free_pitch:
        _unlock(moving, before, axes)
    return _Serial(moving, before, acc, axes)


def _unlock(moving: list[_Joint], before: list[Array], axes: list[Array]) -> None:
    """In place: turn a joint's model frame about its own axis (R_i <- R_i Rz(phi), free:
    the next placement absorbs it) wherever its placement would have pitch near +-pi/2, where
    roll and yaw turn about one axis and the error model 'full' loses a parameter (an axis y
    after an axis x converts to pitch -pi/2). phi = pi/2 (exact) when it frees the pitch."""
    prev = np.eye(4)
    for i, (joint, F) in enumerate(zip(moving, before)):
        M = (prev.T @ F @ joint.origin @ axes[i])[:3, :3]
        if abs(M[2, 0]) > GIMBAL_SIN:        # M[2, 0] = -sin(pitch)
            turn = np.eye(4)
            c, s = (0.0, 1.0) if abs(M[2, 1]) <= GIMBAL_SIN else _level(M)
            turn[:2, :2] = [[c, -s], [s, c]]
            axes[i] = axes[i] @ turn
        prev = axes[i]


def _level(M: Array) -> tuple[float, float]:
    """(cos, sin) of the turn phi about z with (M Rz(phi))[2, 0] = 0 (pitch 0)."""
    phi = math.atan2(-M[2, 0], M[2, 1])
    return math.cos(phi), math.sin(phi)


def _placements(serial: _Serial) -> list[Array]:
    """Model placements P_i = R_{i-1}^T F_i O_i R_i (R_0 = I)."""
    out, prev = [], np.eye(4)
    for joint, F, R in zip(serial.moving, serial.before, serial.axes):
        out.append(prev.T @ F @ joint.origin @ R)
        prev = R
    return out


def _literal(serial: _Serial) -> list[bool]:
    """Per moving joint: is its model placement exactly its URDF origin (no conversion)?"""
    out, prev_identity = [], True
    for F, R in zip(serial.before, serial.axes):
        identity = np.array_equal(R, np.eye(4))
        out.append(prev_identity and identity and np.array_equal(F, np.eye(4)))
        prev_identity = identity
    return out


# --- public API --------------------------------------------------------------------------

def model_from_urdf(text: str, base_link: str, tip_link: str, name: str, *,
                    free_pitch: bool = False) -> KinematicModel:
    """Model (kind 'origin') of the revolute chain from ``base_link`` to ``tip_link``.

    fk(model.chain(), q) is T_base_link_tip_link, q in the order of the revolute/continuous/
    prismatic joints on the path (continuous joints get limits +-inf; a prismatic joint slides
    along its axis, q in m). A joint whose origin needs no
    conversion (no fixed joint before it, +z axis here and on the previous revolute joint)
    keeps the URDF's literal xyz/rpy as its parameters. ``free_pitch``: no placement near
    gimbal lock (module docstring; a literal joint there is converted), for identification.
    ValueError (naming the link/joint) for malformed XML or numbers, unknown links, no serial
    path, floating/planar/mimic joints on the path, xacro text.
    """
    urdf = _parse(text)
    serial = _serial(_path(urdf, base_link, tip_link), base_link, tip_link, free_pitch)
    rows = []
    for joint, literal, P in zip(serial.moving, _literal(serial), _placements(serial)):
        if literal:
            rows.append(list(joint.xyz) + list(joint.rpy))
        else:
            rows.append(list(P[:3, 3]) + list(rpy_from_matrix(P)))
    flange = serial.axes[-1].T @ serial.after
    limits = [(j.lower, j.upper) for j in serial.moving]
    names = tuple(j.name for j in serial.moving)
    return _model(name, 'origin', names, rows, limits, flange,
                  [j.type == 'prismatic' for j in serial.moving])


def _tool_matrix(p_flange_tool: ArrayLike | None) -> Array:
    T = np.eye(4)
    if p_flange_tool is not None:
        xyz = np.asarray(p_flange_tool, dtype=float)
        if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
            raise ValueError(f'p_flange_tool: expected 3 finite numbers [m], got {p_flange_tool!r}')
        T[:3, 3] = xyz
    return T


def _set_origin(joint: ET.Element, T: Array | None = None, *,
                xyz_rpy: tuple[ArrayLike, ArrayLike] | None = None) -> None:
    """Write <origin xyz rpy> of a joint element from T (4, 4) or literal (xyz, rpy)."""
    xyz, rpy = (T[:3, 3], rpy_from_matrix(T)) if xyz_rpy is None else xyz_rpy
    origin = joint.find('origin')
    if origin is None:
        origin = ET.Element('origin')
        joint.insert(0, origin)
    origin.set('xyz', _fmt(xyz))
    origin.set('rpy', _fmt(rpy))


def calibrated_urdf(model: KinematicModel, params: ArrayLike,
                    p_flange_tool: ArrayLike | None = None, *, robot_name: str, base_link: str = 'base_link', tool_link: str = 'tool0',
                    original_text: str | None = None) -> str:
    """URDF text whose chain base_link -> tool_link is
    fk(model.chain(params, Trans(p_flange_tool))).

    With ``original_text``: :func:`rewrite_urdf` of it (links, meshes, limits kept), and the
    tool: ``tool_link``, if it exists, must hang below the last model joint through fixed
    joints only, and the fixed joint above it is rewritten; otherwise a fixed joint
    ``<tool_link>_joint`` is added on the last joint's child. The robot is renamed
    ``robot_name``.

    Without it: a minimal kinematic URDF, links ``base_link``, ``link_1`` .. ``link_n``,
    ``tool_link``; revolute joints named as the model's with origin xyz/rpy from each
    placement, axis 0 0 1, the model's limits (continuous when infinite; effort/velocity 0 as
    placeholders), and a fixed joint ``<tool_link>_joint`` at flange @ tool.
    """
    rows = model.rows(params)  # ValueError on a wrong size
    if not np.all(np.isfinite(rows)):
        raise ValueError('params must be finite')
    tool = _tool_matrix(p_flange_tool)
    if original_text is None:
        return _minimal_urdf(model, model.chain(params).placements, model.flange @ tool,
                             robot_name, base_link, tool_link)
    return rewrite_urdf(original_text, model, params, base_link=base_link, tool_link=tool_link,
                        tool=tool, robot_name=robot_name)


def rewrite_urdf(text: str, model: KinematicModel, params: ArrayLike, *, base_link: str,
                 tip_link: str | None = None, tool_link: str | None = None,
                 tool: ArrayLike | None = None, robot_name: str | None = None,
                 note: str = '') -> str:
    """The URDF ``text`` with only the origins of its chain's moving joints changed, so that
    every link of the chain sits where the model with ``params`` puts it; everything else
    (links, visuals, collisions, limits, joints off the chain, comments) is kept.

    The model's joints are the URDF's moving joints from ``base_link``: by name when the
    URDF has them all, else in order up to ``tip_link`` (a model with its own frames, e.g. a
    modified-DH table). Each URDF link frame must be fixed to its model joint frame (checked at
    the nominal parameters: the URDF joint axis is the model's z through the same point); the
    link keeps that fixed transform C_i, so joint i's origin becomes
    F_i^-1 C_{i-1}^-1 P_i C_i (F_i the fixed joints before it, P_i the calibrated placement; a
    joint zero offset thus folds into the origin as a turn about the joint axis). At the
    nominal parameters the origins come back unchanged up to rounding, and a model built from
    this text (:func:`model_from_urdf`) has its literal xyz/rpy written as they are.

    ``tool_link``: also place that link at flange @ ``tool`` (see :func:`calibrated_urdf`).
    ``note``: an XML comment put first in <robot> (which calibration this is).
    ``robot_name``: rename the robot (default: keep the name, which an SRDF refers to).
    ValueError when the chain does not match the model.
    """
    rows = model.rows(params)
    if not np.all(np.isfinite(rows)):
        raise ValueError('params must be finite')
    urdf = _parse(text)
    serial, frames, literal = _chain_frames(urdf, model, base_link, tip_link)
    placements = model.chain(params).placements
    for i, (joint, F, P) in enumerate(zip(serial.moving, serial.before, placements)):
        if literal[i]:  # the parameters are this joint's xyz/rpy: write them as they are
            _set_origin(joint.element, xyz_rpy=(rows[i, :3], rows[i, 3:]))
        else:
            _set_origin(joint.element, invert(F) @ invert(frames[i]) @ P @ frames[i + 1])
    if tool_link is not None:
        end = model.flange @ (np.eye(4) if tool is None else np.asarray(tool, dtype=float))
        _place_tool(urdf, serial.moving[-1].child, tool_link, invert(frames[-1]) @ end)
    if robot_name is not None:
        urdf.root.set('name', robot_name)
    if note:
        comment = ET.Comment(f' {note.replace("--", "- -")} ')
        comment.tail = urdf.root.text or '\n'
        urdf.root.insert(0, comment)
    return '<?xml version="1.0" ?>\n' + ET.tostring(urdf.root, encoding='unicode') + '\n'


def _chain_frames(urdf: _Urdf, model: KinematicModel, base_link: str, tip_link: str | None
                  ) -> tuple[_Serial, list[Array], list[bool]]:
    """The URDF chain of the model's joints, the fixed transforms C_0 = I, C_1 .. C_n from
    each model joint frame to its URDF child link frame (at q = 0), and per joint whether its
    parameters are its literal URDF xyz/rpy. ValueError naming what does not match."""
    if tip_link is not None:
        tip = tip_link
    elif all(name in urdf.joints for name in model.joint_names):
        tip = urdf.joints[model.joint_names[-1]].child
    else:
        raise ValueError(f'the joints of model {model.name!r} are not all in the URDF; name '
                         'the link at the end of its chain (tip_link) to match them in order')
    path, below = _path(urdf, base_link, tip), []
    while path and path[-1].type not in _MOVING:
        below.insert(0, path.pop())
    serial = _serial(path, base_link, tip)
    names = tuple(j.name for j in serial.moving)
    if len(names) != len(model.joint_names) or (
            set(model.joint_names) <= set(urdf.joints) and names != model.joint_names):
        raise ValueError(f'the moving joints from {base_link!r} to {tip!r} are {list(names)}, '
                         f'the model has {list(model.joint_names)}; pass the base_link the '
                         'model was built from')
    for joint, slides in zip(serial.moving, model.prismatic):
        if (joint.type == 'prismatic') != bool(slides):
            raise ValueError(f'joint {joint.name!r} is {joint.type} in the URDF but '
                             f'{"prismatic" if slides else "revolute"} in model {model.name!r}')
    frames = [np.eye(4)]
    for joint, F, P in zip(serial.moving, serial.before, model.chain().placements):
        C = invert(P) @ frames[-1] @ F @ joint.origin
        axis = joint.axis / np.linalg.norm(joint.axis)
        if not (np.allclose(C[:3, :3] @ axis, [0, 0, 1], rtol=0, atol=1e-9)
                and np.allclose(C[:2, 3], 0, rtol=0, atol=1e-9)):
            raise ValueError(f'joint {joint.name!r}: its axis is not the nominal model joint '
                             f'{model.joint_names[len(frames) - 1]!r} of {model.name!r} (the '
                             'URDF link frames are not fixed to the model frames); build the '
                             'model from this URDF (model_from_urdf)')
        frames.append(C)
    if tip_link is not None:
        _check_tip(model, frames[-1], below, tip_link)
    for turned in (False, True):   # a model built from this URDF: its exact axis frames
        exact = _serial(path, base_link, tip, turned)
        if all(np.allclose(C, R.T, rtol=0, atol=1e-9) for C, R in zip(frames[1:], exact.axes)):
            literal = _literal(exact) if model.kind == 'origin' else [False] * len(names)
            return exact, [np.eye(4)] + [R.T for R in exact.axes], literal
    return serial, frames, [False] * len(names)


def _check_tip(model: KinematicModel, C_last: Array, below: list[_Joint], tip_link: str) -> None:
    """ValueError unless ``tip_link`` (fixed joints ``below`` the last moving one) is the
    model's flange at the nominal parameters: a joint origin shifted along or turned about its
    axis passes the axis check but moves everything after it."""
    T = C_last
    for joint in below:
        T = T @ joint.origin
    gap = invert(model.flange) @ T
    offset, angle = float(np.linalg.norm(gap[:3, 3])), rotation_angle(gap)
    if offset > 1e-9 or angle > 1e-9:
        raise ValueError(f'tip_link {tip_link!r} is {offset * 1e3:.6g} mm / {angle * 1e3:.6g} '
                         f'mrad from the flange of model {model.name!r} at the nominal '
                         'parameters: the URDF and the model describe different arms (or name '
                         "the model's flange link as tip_link)")


def _minimal_urdf(model: KinematicModel, placements: Array, end: Array, robot_name: str,
                  base_link: str, tool_link: str) -> str:
    n = len(model.joint_names)
    links = [base_link] + [f'link_{i}' for i in range(1, n + 1)] + [tool_link]
    tool_joint = f'{tool_link}_joint'
    if len(set(links)) != len(links) or tool_joint in model.joint_names:
        raise ValueError(f'link/joint names collide: base_link {base_link!r}, tool_link '
                         f'{tool_link!r}, generated links link_1..link_{n}, joint '
                         f'{tool_joint!r}; choose other base_link/tool_link names')
    robot = ET.Element('robot', name=robot_name)
    for link in links:
        ET.SubElement(robot, 'link', name=link)
    for i, joint_name in enumerate(model.joint_names):
        lo, hi = float(model.lower[i]), float(model.upper[i])
        bounded = math.isfinite(lo) and math.isfinite(hi)
        kind = 'prismatic' if model.prismatic[i] else 'revolute' if bounded else 'continuous'
        joint = ET.SubElement(robot, 'joint', name=joint_name, type=kind)
        _set_origin(joint, placements[i])
        ET.SubElement(joint, 'parent', link=links[i])
        ET.SubElement(joint, 'child', link=links[i + 1])
        ET.SubElement(joint, 'axis', xyz='0 0 1')
        if bounded:
            ET.SubElement(joint, 'limit', lower=repr(lo), upper=repr(hi), effort='0',
                          velocity='0')
    joint = ET.SubElement(robot, 'joint', name=tool_joint, type='fixed')
    _set_origin(joint, end)
    ET.SubElement(joint, 'parent', link=links[n])
    ET.SubElement(joint, 'child', link=tool_link)
    return _serialise(robot)


def _serialise(root: ET.Element) -> str:
    ET.indent(root, space='  ')
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding='unicode') + '\n'


def _place_tool(urdf: _Urdf, last_child: str, tool_link: str, target: Array) -> None:
    if tool_link not in urdf.links:
        tool_joint = f'{tool_link}_joint'
        if tool_joint in urdf.joints:
            raise ValueError(f'cannot add joint {tool_joint!r}: the name is taken')
        link = ET.SubElement(urdf.root, 'link', name=tool_link)
        link.tail = '\n'
        joint = ET.SubElement(urdf.root, 'joint', name=tool_joint, type='fixed')
        _set_origin(joint, target)
        ET.SubElement(joint, 'parent', link=last_child)
        ET.SubElement(joint, 'child', link=tool_link)
        ET.indent(joint, space='  ', level=1)
        joint.tail = '\n'
        return
    if tool_link == last_child:
        raise ValueError(f'tool_link {tool_link!r} is the link of the last joint; name a link '
                         'below it (or a new one)')
    chain, link = [], tool_link
    while link != last_child:
        joint = urdf.parent_joint.get(link)
        if joint is None or joint.type != 'fixed':
            raise ValueError(f'tool_link {tool_link!r} exists but is not attached below '
                             f'{last_child!r} through fixed joints only; choose a new link '
                             'name or one on that fixed chain')
        chain.append(joint)
        link = joint.parent
    above = np.eye(4)
    for joint in reversed(chain[1:]):
        above = above @ joint.origin
    _set_origin(chain[0].element, invert(above) @ target)
