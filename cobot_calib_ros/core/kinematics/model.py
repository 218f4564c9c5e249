"""Serial-arm kinematics: parametrised nominal models, vectorised FK, pinocchio IK.

A :class:`Chain` is a serial chain of revolute joints. Joint ``i`` sits at a fixed placement
(4, 4) in the previous joint frame and then turns by ``q_i`` about its local z axis:

    T_base_tool = P_1 Rz(q_1) P_2 Rz(q_2) ... P_n Rz(q_n) @ flange @ tool

(a joint marked ``prismatic`` slides by ``q_i`` [m] along its local z instead: Tz(q_i)).

Craig's modified DH link ``RotX(alpha) TransX(a) RotZ(theta + q) TransZ(d)`` has this form with
``P = RotX(alpha) TransX(a) RotZ(theta) TransZ(d)`` (RotZ commutes with TransZ), and so does a
URDF joint origin ``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` with axis z. Transform names
follow :mod:`cobot_calib_ros.core.frames`: ``T_a_b`` is the pose of ``b`` in ``a``. Lengths are
metres, angles radians.

A :class:`KinematicModel` maps a flat parameter vector (``kind='mdh'``: alpha, a, theta, d per
joint; ``kind='origin'``: x, y, z, roll, pitch, yaw per joint) to a :class:`Chain`, so that a
"true" robot can differ from the nominal one and identification can optimise the parameters.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

# Per kind: parameter field names, and the placement as a product of elementary motions
# (motion 'r' rotation / 't' translation, local axis 0/1/2, index of the field giving its value).
_FIELDS = {'mdh': ('alpha', 'a', 'theta', 'd'),
           'origin': ('x', 'y', 'z', 'roll', 'pitch', 'yaw')}
_MOTIONS = {'mdh': (('r', 0, 0), ('t', 0, 1), ('r', 2, 2), ('t', 2, 3)),
            'origin': (('t', 0, 0), ('t', 1, 1), ('t', 2, 2), ('r', 2, 5), ('r', 1, 4),
                       ('r', 0, 3))}


def _identity() -> Array:
    return np.eye(4)


def _frozen(values: ArrayLike, shape: tuple[int, ...], what: str) -> Array:
    """Read-only float copy of ``values``; ValueError unless it has ``shape``."""
    a = np.array(values, dtype=float)
    if a.shape != shape:
        raise ValueError(f'{what}: expected shape {shape}, got {a.shape}')
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Chain:
    """Serial revolute chain; arrays are copied and made read-only on construction.

    Compares by identity (so it can key a cache); compare arrays explicitly if needed.
    """

    joint_names: tuple[str, ...]
    placements: Array  # (n, 4, 4), previous joint frame (base for i = 0) -> joint i at q_i = 0
    tool: Array = field(default_factory=_identity)  # (4, 4) T_flange_tool, tool centre point
    lower: Array = field(default_factory=lambda: np.empty(0))  # (n,) [rad]; empty: -inf
    upper: Array = field(default_factory=lambda: np.empty(0))  # (n,) [rad]; empty: +inf
    flange: Array = field(default_factory=_identity)  # (4, 4) last joint frame -> flange
    prismatic: Array = field(default_factory=lambda: np.empty(0, bool))  # (n,); empty: none

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        prismatic = np.zeros(n, bool) if np.size(self.prismatic) == 0 else np.array(
            self.prismatic, dtype=bool)
        if prismatic.shape != (n,):
            raise ValueError(f'prismatic: expected shape ({n},), got {prismatic.shape}')
        prismatic.setflags(write=False)
        object.__setattr__(self, 'prismatic', prismatic)
        lower = np.full(n, -np.inf) if np.size(self.lower) == 0 else self.lower
        upper = np.full(n, np.inf) if np.size(self.upper) == 0 else self.upper
        object.__setattr__(self, 'joint_names', tuple(self.joint_names))
        object.__setattr__(self, 'placements', _frozen(self.placements, (n, 4, 4), 'placements'))
        object.__setattr__(self, 'tool', _frozen(self.tool, (4, 4), 'tool'))
        object.__setattr__(self, 'lower', _frozen(lower, (n,), 'lower'))
        object.__setattr__(self, 'upper', _frozen(upper, (n,), 'upper'))
        object.__setattr__(self, 'flange', _frozen(self.flange, (4, 4), 'flange'))

    @property
    def dof(self) -> int:
        return len(self.joint_names)


def _as_batch(chain: 'Chain | KinematicModel', q: ArrayLike) -> Array:
    """(n,) or (m, n) joint angles [rad] -> (m, n); ValueError on a wrong shape."""
    qa = np.asarray(q, dtype=float)
    n = len(chain.joint_names)
    if qa.ndim not in (1, 2) or qa.shape[-1] != n:
        raise ValueError(f'expected q of shape ({n},) or (m, {n}), got {qa.shape}')
    return qa.reshape(-1, n)


def _right_mul(T: Array, M: Array) -> Array:
    """(m, 4, 4) stack times one (4, 4), as a single (4m, 4) @ (4, 4) product."""
    return (T.reshape(-1, 4) @ M).reshape(T.shape)


def _turn_z(T: Array, angles: Array) -> None:
    """In place: T[k] <- T[k] @ Rz(angles[k]) for a (m, 4, 4) stack of rigid transforms,
    angles (m,) [rad]."""
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    x, y = T[:, :3, 0].copy(), T[:, :3, 1]     # the bottom row (0, 0, 0, 1) stays
    T[:, :3, 0] = c * x + s * y
    T[:, :3, 1] = c * y - s * x


def fk(chain: Chain, q: ArrayLike) -> Array:
    """Pose of the tool in base, T_base_tool.

    q (n,) [rad] -> (4, 4); q (m, n) -> (m, 4, 4). Vectorised over configurations.
    """
    T = fk_placements(chain.placements, chain.flange @ chain.tool, _as_batch(chain, q),
                      chain.prismatic)
    return T[0] if np.ndim(q) == 1 else T


def _move_joint(T: Array, q: Array, prismatic: bool) -> None:
    """In place: T <- T Rz(q) (revolute, q [rad]) or T Tz(q) (prismatic, q [m])."""
    if prismatic:
        T[:, :3, 3] += T[:, :3, 2] * q[:, None]
    else:
        _turn_z(T, q)


def fk_placements(placements: ArrayLike, end: Array, q: Array,
                  prismatic: ArrayLike | None = None) -> Array:
    """(m, 4, 4) P_1 M(q_1) ... P_n M(q_n) end for placements (n, 4, 4), q (m, n), M = Rz
    (revolute, [rad]) or Tz (``prismatic`` joints, [m]): :func:`fk` without building a Chain
    (identification varies one placement at a time)."""
    slide = np.zeros(len(placements), bool) if prismatic is None or np.size(prismatic) == 0 \
        else np.asarray(prismatic, dtype=bool)
    T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    for i, P in enumerate(placements):
        T = _right_mul(T, P)
        _move_joint(T, q[:, i], bool(slide[i]))
    return _right_mul(T, end)


# --- parametrised models -------------------------------------------------------------------

def _motion(kind: str, axis: int, value: float) -> Array:
    """(4, 4) elementary rotation ('r') or translation ('t') along a local axis [rad or m]."""
    T = np.eye(4)
    if kind == 't':
        T[axis, 3] = value
        return T
    c, s = math.cos(value), math.sin(value)
    j, k = (axis + 1) % 3, (axis + 2) % 3
    T[j, j], T[j, k], T[k, j], T[k, k] = c, -s, s, c
    return T


def placement(kind: str, row: ArrayLike) -> Array:
    """(4, 4) joint placement from one parameter row (alpha, a, theta, d) or (x..yaw)."""
    r = np.asarray(row, dtype=float)
    T = np.eye(4)
    for motion, axis, idx in _MOTIONS[kind]:
        T = T @ _motion(motion, axis, r[idx])
    return T


@dataclass(frozen=True, eq=False)
class KinematicModel:
    """Nominal kinematic model with a flat parameter vector (SI units: m, rad)."""

    name: str                          # 'iiwa7', 'iiwa14', 'sawyer', 'ur10'
    kind: str                          # 'mdh' or 'origin'
    joint_names: tuple[str, ...]
    nominal: Array                     # (n * 4,) for 'mdh', (n * 6,) for 'origin'
    parameter_names: tuple[str, ...]   # 'alpha_1', 'a_1', ... or 'x_right_j0', ...
    lower: Array                       # (n,) joint limits [rad]
    upper: Array                       # (n,) joint limits [rad]
    flange: Array = field(default_factory=_identity)  # fixed last joint frame -> flange
    prismatic: Array = field(default_factory=lambda: np.empty(0, bool))  # (n,); empty: none

    @property
    def fields_per_joint(self) -> int:
        return len(_FIELDS[self.kind])

    def rows(self, params: ArrayLike | None = None) -> Array:
        """Parameters as (n, 4) or (n, 6) rows; ValueError on a wrong size."""
        p = self.nominal if params is None else np.asarray(params, dtype=float)
        if p.shape != self.nominal.shape:
            raise ValueError(f'expected {self.nominal.shape} parameters, got {p.shape}')
        return p.reshape(len(self.joint_names), self.fields_per_joint)

    def chain(self, params: ArrayLike | None = None, tool: ArrayLike | None = None) -> Chain:
        """Chain for ``params`` (default nominal) with T_flange_tool ``tool`` (default I)."""
        placements = np.stack([placement(self.kind, r) for r in self.rows(params)])
        return Chain(self.joint_names, placements, _identity() if tool is None else tool,
                     self.lower, self.upper, self.flange, self.prismatic)


def _model(name: str, kind: str, joint_names: tuple[str, ...], rows: ArrayLike,
           limits: ArrayLike, flange: Array | None = None,
           prismatic: ArrayLike | None = None) -> KinematicModel:
    """Assemble a model; rows (n, k) in m/rad, limits (n, 2) [rad, or m for prismatic]."""
    r = np.asarray(rows, dtype=float)
    lim = np.asarray(limits, dtype=float)
    suffixes = [str(i + 1) for i in range(len(r))] if kind == 'mdh' else list(joint_names)
    names = tuple(f'{f}_{s}' for s in suffixes for f in _FIELDS[kind])
    return KinematicModel(name, kind, joint_names, r.ravel(), names, lim[:, 0], lim[:, 1],
                          _identity() if flange is None else flange,
                          np.zeros(len(r), bool) if prismatic is None else
                          np.asarray(prismatic, dtype=bool))


def _iiwa(name: str, d1: float, d3: float) -> KinematicModel:
    """KUKA LBR iiwa MDH [alpha, a, theta, d] (m, rad); the last d puts frame 7 at the flange."""
    h = math.pi / 2
    rows = [[0, 0, 0, d1], [-h, 0, 0, 0], [h, 0, 0, d3], [h, 0, 0, 0],
            [-h, 0, 0, 0.400], [-h, 0, 0, 0], [h, 0, 0, 0.126]]
    limits_deg = [170, 120, 170, 120, 170, 120, 175]
    limits = [(-math.radians(v), math.radians(v)) for v in limits_deg]
    names = tuple(f'joint_a{i}' for i in range(1, 8))
    return _model(name, 'mdh', names, rows, limits)


def iiwa7() -> KinematicModel:
    """KUKA LBR iiwa 7 R800 (pybotics ``kuka_lbr_iiwa_7`` MDH, in m), flange frame at the end."""
    return _iiwa('iiwa7', 0.340, 0.400)


def iiwa14() -> KinematicModel:
    """KUKA LBR iiwa 14 R820: as iiwa7 with d1 = 0.360 m, d3 = 0.420 m."""
    return _iiwa('iiwa14', 0.360, 0.420)


def ur10_pybotics() -> KinematicModel:
    """UR10 MDH table of pybotics ``ur10()`` (mm there), in m; limits +-2 pi (UR +-360 deg)."""
    h, pi = math.pi / 2, math.pi
    rows_mm = [[0, 0, 0, 118], [h, 0, pi, 0], [0, 612.7, 0, 0], [0, 571.6, 0, 163.9],
               [-h, 0, 0, 115.7], [h, 0, pi, 92.2]]
    rows = np.array(rows_mm) * [1.0, 1e-3, 1.0, 1e-3]
    names = tuple(f'joint_{i}' for i in range(1, 7))
    return _model('ur10', 'mdh', names, rows, [(-2 * pi, 2 * pi)] * 6)


_H = 1.57079632679  # pi/2 as rounded in the Sawyer URDF
# name, xyz [m], rpy [rad], limits [rad]: sawyer_description/urdf/sawyer_base.urdf.xacro
# (RethinkRobotics/sawyer_robot d1ef3d0), non-gazebo limits.
_SAWYER = (
    ('right_j0', (0.0, 0.0, 0.08), (0.0, 0.0, 0.0), (-3.0503, 3.0503)),
    ('right_j1', (0.081, 0.05, 0.237), (-_H, _H, 0.0), (-3.8095, 2.2736)),
    ('right_j2', (0.0, -0.14, 0.1425), (_H, 0.0, 0.0), (-3.0426, 3.0426)),
    ('right_j3', (0.0, -0.042, 0.26), (-_H, 0.0, 0.0), (-3.0439, 3.0439)),
    ('right_j4', (0.0, -0.125, -0.1265), (_H, 0.0, 0.0), (-2.9761, 2.9761)),
    ('right_j5', (0.0, 0.031, 0.275), (-_H, 0.0, 0.0), (-2.9761, 2.9761)),
    ('right_j6', (0.0, -0.11, 0.1053), (-_H, -0.17453, 3.1416), (-4.7124, 4.7124)),
)
_SAWYER_HAND = ((0.0, 0.0, 0.0245), (0.0, 0.0, 1.570796))  # fixed right_l6 -> right_hand


def sawyer() -> KinematicModel:
    """Rethink Sawyer arm from URDF joint origins; fk(tool=I) is right_hand in right_arm_base_link.

    right_j6 limits are the real-robot +-4.7124 rad (the URDF's gazebo branch says +-3.14, which
    would exclude the named 'neutral' pose, q6 = 3.3161).
    """
    names = tuple(j[0] for j in _SAWYER)
    rows = [list(j[1]) + list(j[2]) for j in _SAWYER]
    flange = placement('origin', list(_SAWYER_HAND[0]) + list(_SAWYER_HAND[1]))
    return _model('sawyer', 'origin', names, rows, [j[3] for j in _SAWYER], flange)


def dh_model(name: str, joint_names: tuple[str, ...], dh_rows: ArrayLike,
             limits: ArrayLike) -> KinematicModel:
    """MDH model (kind 'mdh') of a standard DH table, rows (d, theta, r, alpha) [m, rad].

    Standard DH link i, Rz(theta_i + q_i) Tz(d_i) Tx(r_i) Rx(alpha_i), regrouped around the
    joint rotations: MDH row i is (alpha_{i-1}, r_{i-1}, theta_i, d_i) with alpha_0 = r_0 = 0
    (Tx and Rx commute, as do Rz and Tz), and the last link's Tx(r_n) Rx(alpha_n) is the
    flange. Same FK; the MDH parameters are the DH table's, moved one row down.
    """
    dh = np.asarray(dh_rows, dtype=float)
    if dh.ndim != 2 or dh.shape[1] != 4 or len(dh) != len(joint_names) \
            or not np.all(np.isfinite(dh)):
        raise ValueError(f'DH table: expected {len(joint_names)} finite rows (d, theta, r, '
                         f'alpha), got shape {dh.shape}')
    d, theta, r, alpha = dh.T
    rows = np.stack([np.concatenate([[0.0], alpha[:-1]]), np.concatenate([[0.0], r[:-1]]),
                     theta, d], axis=1)
    flange = _motion('t', 0, r[-1]) @ _motion('r', 0, alpha[-1])
    return _model(name, 'mdh', tuple(joint_names), rows, limits, flange)


def _moving_axes(model: KinematicModel, params: ArrayLike | None,
                 q: Array) -> Iterator[tuple[bool, int, bool, Array, Array]]:
    """Along the chain at q (m, n): (is a joint, its parameter or joint index, turns (else
    slides), axis u (m, 3), a point o on it (m, 3)) in the base frame, for every parameter's
    elementary motion and every joint."""
    rows = model.rows(params)
    slide = np.zeros(len(rows), bool) if np.size(model.prismatic) == 0 else model.prismatic
    T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    k = model.fields_per_joint
    for i, row in enumerate(rows):
        for motion, axis, idx in _MOTIONS[model.kind]:
            T = _right_mul(T, _motion(motion, axis, row[idx]))
            yield False, i * k + idx, motion == 'r', T[:, :3, axis], T[:, :3, 3]
        yield True, i, not slide[i], T[:, :3, 2], T[:, :3, 3]
        _move_joint(T, q[:, i], bool(slide[i]))


def parameter_twists(model: KinematicModel, params: ArrayLike | None,
                     q_batch: ArrayLike) -> tuple[Array, Array]:
    """Twists (v, w) in the base frame of every parameter (P, m, 6) and every joint (n, m, 6).

    Moving parameter k (or joint i) by h moves everything past it rigidly: to first order every
    point p of the tool side goes to p + h (v + w x p) and rotations R to R + h [w]x R. A
    rotation about the unit axis u through o has w = u, v = o x u; a translation along u has
    v = u, w = 0. q_batch (m, n) [rad]; params default nominal. Independent of the tool.
    """
    q = _as_batch(model, q_batch)
    twists = np.zeros((model.nominal.size, len(q), 6))
    joints = np.zeros((len(model.joint_names), len(q), 6))
    for is_joint, index, turns, u, o in _moving_axes(model, params, q):
        out = (joints if is_joint else twists)[index]
        if turns:
            out[:, :3], out[:, 3:] = _cross(o, u), u
        else:
            out[:, :3] = u
    return twists, joints


def _cross(a: Array, b: Array) -> Array:
    """(m, 3) rows a x b (np.cross's general path costs twice this here)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def position_jacobian_wrt_params(model: KinematicModel, params: ArrayLike | None,
                                 q_batch: ArrayLike, tool: ArrayLike | None = None) -> Array:
    """Analytic d(tool position)/d(params), shape (m, 3, P) [m/m or m/rad].

    q_batch (m, n) [rad]; params default nominal; tool T_flange_tool (default I), held fixed.
    Reshape to (3 m, P) for a stacked least-squares Jacobian.
    """
    chain = model.chain(params, tool)
    q = _as_batch(chain, q_batch)
    p_tool = fk(chain, q)[:, :3, 3]
    J = np.empty((len(q), 3, model.nominal.size))
    for is_joint, index, turns, u, o in _moving_axes(model, params, q):
        if not is_joint:
            J[:, :, index] = np.cross(u, p_tool - o) if turns else u
    return J
