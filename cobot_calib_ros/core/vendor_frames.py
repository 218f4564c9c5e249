"""A frame in each robot controller's own numbers, and back: KUKA, ABB, FANUC, UR, Yaskawa.

Every format takes and gives a (4, 4) transform ``T_a_b`` in SI (core.frames); the vendor
values are in the controller's units, in its field order:

=========  ===========================================  =========================================
format     values                                       rotation
=========  ===========================================  =========================================
kuka       X, Y, Z [mm], A, B, C [deg]                  R = Rz(A) Ry(B) Rx(C)  (KRL FRAME)
abb        x, y, z [mm], q1, q2, q3, q4                 unit quaternion, q1 the scalar, q1 >= 0
fanuc      X, Y, Z [mm], W, P, R [deg]                  R = Rz(R) Ry(P) Rx(W)
ur         x, y, z [m], rx, ry, rz [rad]                rotation vector (URScript ``p[...]``)
yaskawa    X, Y, Z [mm], Rx, Ry, Rz [deg]               R = Rz(Rz) Ry(Ry) Rx(Rx)
=========  ===========================================  =========================================

Euler angles are wrapped to (-180, 180]; at the gimbal lock (B, P or Ry = +-90 deg) only A - C
(or A + C) is defined and C (W, Rx) is set to 0, as RoboDK's ``Pose_2_KUKA`` does. The UR
rotation vector has an angle in [0, pi]. :func:`paste_text` writes the values as the
controller's program or configuration syntax: a frame (KUKA BASE_DATA, ABB wobjdata, FANUC
UFRAME, UR pose, Yaskawa user frame) or a tool (KUKA TOOL_DATA, ABB tooldata, FANUC UTOOL, UR
set_tcp, Yaskawa TOOL screen values).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import make_transform, rot_x, rot_y, rot_z, Rotation

Array = NDArray[np.float64]
MM = 1e-3                  # [m]
GIMBAL_EPS = 1e-12         # |cos B| below this: gimbal lock


@dataclass(frozen=True)
class VendorFormat:
    name: str
    labels: tuple[str, ...]
    units: tuple[str, ...]


FORMATS = {
    'kuka': VendorFormat('kuka', ('X', 'Y', 'Z', 'A', 'B', 'C'), ('mm',) * 3 + ('deg',) * 3),
    'abb': VendorFormat('abb', ('x', 'y', 'z', 'q1', 'q2', 'q3', 'q4'), ('mm',) * 3 + ('',) * 4),
    'fanuc': VendorFormat('fanuc', ('X', 'Y', 'Z', 'W', 'P', 'R'), ('mm',) * 3 + ('deg',) * 3),
    'ur': VendorFormat('ur', ('x', 'y', 'z', 'rx', 'ry', 'rz'), ('m',) * 3 + ('rad',) * 3),
    'yaskawa': VendorFormat('yaskawa', ('X', 'Y', 'Z', 'Rx', 'Ry', 'Rz'),
                            ('mm',) * 3 + ('deg',) * 3),
}


def _wrap_deg(angle: float) -> float:
    """An angle [deg] in (-180, 180]."""
    wrapped = math.remainder(angle, 360.0)
    return 180.0 if wrapped == -180.0 else wrapped + 0.0   # + 0.0: no -0.0


def zyx_angles(R: ArrayLike) -> tuple[float, float, float]:
    """(a, b, c) [deg] with R = Rz(a) Ry(b) Rx(c), b in [-90, 90]; c = 0 at the gimbal lock."""
    R = np.asarray(R, dtype=float)
    cos_b = math.hypot(R[0, 0], R[1, 0])
    b = math.atan2(-R[2, 0], cos_b)
    if cos_b < GIMBAL_EPS:       # b = +-90: R01 = -sin(a -+ c), R11 = cos(a -+ c); take c = 0
        a, c = math.atan2(-R[0, 1], R[1, 1]), 0.0
    else:
        a, c = math.atan2(R[1, 0], R[0, 0]), math.atan2(R[2, 1], R[2, 2])
    return tuple(_wrap_deg(math.degrees(v)) for v in (a, b, c))


def zyx_matrix(a_deg: float, b_deg: float, c_deg: float) -> Array:
    """Rz(a) Ry(b) Rx(c), angles in degrees."""
    return rot_z(math.radians(a_deg)) @ rot_y(math.radians(b_deg)) @ rot_x(math.radians(c_deg))


def quaternion_wxyz(R: ArrayLike) -> Array:
    """The unit quaternion (w, x, y, z) of R with w >= 0 (at w = 0: first non-zero part > 0)."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()
    q = np.array([w, x, y, z])
    first = next((v for v in q if abs(v) > 1e-15), 1.0)
    return (-q if first < 0 else q) + 0.0

# The frame numbers each controller has (ABB names a wobjdata, UR a variable: no number):
# KUKA KRC4 BASE_DATA[1..32], FANUC UFRAME[1..9] (0 is the world frame), Yaskawa UF#1..63
FRAME_NUMBERS = {'kuka': range(1, 33), 'fanuc': range(1, 10), 'yaskawa': range(1, 64)}
# and the tool numbers (ABB names a tooldata, UR sets the TCP): KUKA KRC4 TOOL_DATA[1..16],
# FANUC UTOOL[1..10] (0 is the flange), Yaskawa tool file 0..63
TOOL_NUMBERS = {'kuka': range(1, 17), 'fanuc': range(1, 11), 'yaskawa': range(0, 64)}


def check_frame_number(fmt: str, index: int | None, numbers_of=FRAME_NUMBERS) -> None:
    """ValueError unless ``index`` (None: not given) is a frame number ``fmt``'s controller
    has (``numbers_of``: TOOL_NUMBERS for a tool); ABB and UR frames have a name, not a
    number."""
    if fmt not in FORMATS:
        raise ValueError(_unknown(fmt))
    numbers = numbers_of.get(fmt)
    if numbers is None:
        if index is not None:
            raise ValueError(f'{fmt} frames have no number: name the variable with --name '
                             'instead of --index')
    elif index is not None and index not in numbers:
        raise ValueError(f'{fmt} frame number {index}: give {numbers[0]}..{numbers[-1]}')


def to_values(T: ArrayLike, fmt: str) -> tuple[float, ...]:
    """The vendor values of ``T`` [m] in ``fmt`` (see the module table). ValueError: unknown
    format or not a rigid transform."""
    T = _check_transform(T)
    R, t = T[:3, :3], T[:3, 3]
    p_mm = tuple(float(v) / MM + 0.0 for v in t)
    if fmt == 'abb':
        return p_mm + tuple(float(v) for v in quaternion_wxyz(R))
    if fmt == 'ur':
        return tuple(float(v) for v in t) + tuple(
            float(v) + 0.0 for v in Rotation.from_matrix(R).as_rotvec())
    a, b, c = zyx_angles(R)
    if fmt == 'kuka':
        return p_mm + (a, b, c)
    if fmt in ('fanuc', 'yaskawa'):
        return p_mm + (c, b, a)
    raise ValueError(_unknown(fmt))


def from_values(values: ArrayLike, fmt: str) -> Array:
    """The (4, 4) transform [m] of vendor values in ``fmt``. ValueError: unknown format, wrong
    count, not finite, or a quaternion far from unit length."""
    if fmt not in FORMATS:
        raise ValueError(_unknown(fmt))
    v = np.asarray(values, dtype=float).ravel()
    expected = len(FORMATS[fmt].labels)
    if v.size != expected or not np.all(np.isfinite(v)):
        raise ValueError(f'{fmt}: expected {expected} finite values '
                         f'({", ".join(FORMATS[fmt].labels)}), got {values!r}')
    if fmt == 'ur':
        return make_transform(Rotation.from_rotvec(v[3:]).as_matrix(), v[:3])
    t = v[:3] * MM
    if fmt == 'abb':
        norm = float(np.linalg.norm(v[3:]))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f'abb: the quaternion {v[3:].tolist()} is not unit length '
                             f'(|q| = {norm:.6f}); give q1 (scalar), q2, q3, q4')
        w, x, y, z = v[3:] / norm
        return make_transform(Rotation.from_quat([x, y, z, w]).as_matrix(), t)
    a, b, c = (v[3], v[4], v[5]) if fmt == 'kuka' else (v[5], v[4], v[3])
    return make_transform(zyx_matrix(a, b, c), t)


def paste_text(T: ArrayLike, fmt: str, name: str = 'cell_frame', index: int | None = None,
               comment: str = '', tool: bool = False) -> str:
    """``T`` (a base or user frame, [m]; ``tool``: a tool centre point in the flange frame)
    as the controller's own syntax, ready to paste, with ``comment`` (e.g. where the frame
    comes from) as the language's comment; ``index`` the frame (tool) number
    (check_frame_number; default 1 where the controller numbers them)."""
    check_frame_number(fmt, index, TOOL_NUMBERS if tool else FRAME_NUMBERS)
    v = to_values(T, fmt)
    index = 1 if index is None else index
    body = (_PASTE_TOOL if tool else _PASTE)[fmt](v, name, index)
    mark = {'kuka': ';', 'abb': '!', 'fanuc': '!', 'ur': '#', 'yaskawa': '//'}[fmt]
    head = [f'{mark} {line}' for line in comment.splitlines()] if comment else []
    return '\n'.join(head + body) + '\n'


def _kuka(v, name, index):
    x, y, z, a, b, c = v
    return [f'BASE_DATA[{index}]={{X {x:.4f},Y {y:.4f},Z {z:.4f},'
            f'A {a:.6f},B {b:.6f},C {c:.6f}}}']


def _abb(v, name, index):
    x, y, z, q1, q2, q3, q4 = v
    return [f'PERS wobjdata {name}:=[FALSE,TRUE,"",[[{x:.4f},{y:.4f},{z:.4f}],'
            f'[{q1:.9f},{q2:.9f},{q3:.9f},{q4:.9f}]],[[0,0,0],[1,0,0,0]]];']


def _fanuc_register(v, name, index, target: str, first_register: int):
    """``target`` (UFRAME or UTOOL) number ``index`` set from position register
    ``first_register + index`` (a free one is assumed), with a comment giving the values."""
    labels = FORMATS['fanuc'].labels
    register = first_register + index
    lines = [f'PR[{register},{k + 1}]={value:.4f} ;' if k < 3 else
             f'PR[{register},{k + 1}]={value:.6f} ;' for k, value in enumerate(v)]
    return ([f'! {target}[{index}] {name}: ' + ' '.join(
        f'{label} {value:.4f}' if k < 3 else f'{label} {value:.6f}'
        for k, (label, value) in enumerate(zip(labels, v)))]
            + lines + [f'{target}[{index}]=PR[{register}] ;'])


def _fanuc(v, name, index):
    return _fanuc_register(v, name, index, 'UFRAME', 50)


def _ur(v, name, index):
    x, y, z, rx, ry, rz = v
    return [f'{name} = p[{x:.7f}, {y:.7f}, {z:.7f}, {rx:.8f}, {ry:.8f}, {rz:.8f}]',
            f'# pendant (mm, rad): X {x / MM:.4f} Y {y / MM:.4f} Z {z / MM:.4f} '
            f'RX {rx:.8f} RY {ry:.8f} RZ {rz:.8f}']


def _yaskawa(v, name, index):
    labels = FORMATS['yaskawa'].labels
    values = ' '.join(f'{label} {value:.4f}' if k < 3 else f'{label} {value:.6f}'
                      for k, (label, value) in enumerate(zip(labels, v)))
    T = from_values(v, 'yaskawa')
    org, xx, xy = (T[:3, 3] + T[:3, :3] @ np.array(p) for p in
                   ((0, 0, 0), (0.1, 0, 0), (0, 0.1, 0)))
    points = [f'// {label} (taught point, mm): ' + ' '.join(f'{c / MM:.4f}' for c in p)
              for label, p in (('ORG', org), ('XX', xx), ('XY', xy))]
    return [f'// UF#{index} {name}: {values}'] + points


_PASTE = {'kuka': _kuka, 'abb': _abb, 'fanuc': _fanuc, 'ur': _ur, 'yaskawa': _yaskawa}


def _kuka_tool(v, name, index):
    x, y, z, a, b, c = v
    return [f'TOOL_DATA[{index}]={{X {x:.4f},Y {y:.4f},Z {z:.4f},'
            f'A {a:.6f},B {b:.6f},C {c:.6f}}}']


def _abb_tool(v, name, index):
    x, y, z, q1, q2, q3, q4 = v
    # tooldata needs a load (mass > 0): a placeholder the user must replace
    return ['! load [1 kg at z 1 mm] is a placeholder: set the real mass and centre of '
            'gravity (LoadIdentify)',
            f'PERS tooldata {name}:=[TRUE,[[{x:.4f},{y:.4f},{z:.4f}],'
            f'[{q1:.9f},{q2:.9f},{q3:.9f},{q4:.9f}]],[1,[0,0,1],[1,0,0,0],0,0,0]];']


def _fanuc_tool(v, name, index):
    return _fanuc_register(v, name, index, 'UTOOL', 60)


def _ur_tool(v, name, index):
    x, y, z, rx, ry, rz = v
    return [f'{name} = p[{x:.7f}, {y:.7f}, {z:.7f}, {rx:.8f}, {ry:.8f}, {rz:.8f}]',
            f'set_tcp({name})',
            f'# Installation > General > TCP (mm, rad): X {x / MM:.4f} Y {y / MM:.4f} '
            f'Z {z / MM:.4f} RX {rx:.8f} RY {ry:.8f} RZ {rz:.8f}']


def _yaskawa_tool(v, name, index):
    labels = FORMATS['yaskawa'].labels
    values = ' '.join(f'{label} {value:.4f}' if k < 3 else f'{label} {value:.6f}'
                      for k, (label, value) in enumerate(zip(labels, v)))
    return [f'// TOOL {index} {name} (the pendant\'s TOOL screen, mm and deg): {values}']


_PASTE_TOOL = {'kuka': _kuka_tool, 'abb': _abb_tool, 'fanuc': _fanuc_tool, 'ur': _ur_tool,
               'yaskawa': _yaskawa_tool}


def _unknown(fmt: str) -> str:
    return f'unknown vendor format {fmt!r}: use one of {", ".join(FORMATS)}'


def _check_transform(T: ArrayLike) -> Array:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f'expected a finite (4, 4) transform, got shape {T.shape}')
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError('not a rigid transform: its rotation part is not orthonormal with '
                         'det +1 (an affine fit? export its T_base_user)')
    return T
