"""Four kinds of measurement of a serial arm, each a residual over the arm's tip pose.

Every kind measures something rigid on the tip link, in a frame the data fix:

- ``points`` (tracker, mocap): marker k's position p in the world frame,
  p = T_world_base T_base_tip(q) m_k; unknowns T_world_base (6) and each marker's m_k (3);
- ``pose`` (a camera on a board): the 6-DoF pose of the target,
  T_world_target = T_world_base T_base_tip(q) T_tip_target; unknowns T_world_base and
  T_tip_target (6 + 6). A camera fixed in the cell measures T_camera_board (world = camera,
  target = board); a camera on the arm measures T_camera_board with the board fixed: the data
  are inverted to T_board_camera (world = board, target = camera). Rotation errors count
  ``rotation_weight`` [m/rad] against position errors (None: balanced, each by its own
  scatter: :func:`..measurement_fit.balanced`);
- ``spheres`` (sphere / socket coupling): the ball centre b (in the tip) is at the same point
  c_s of sphere s every time, with known centre distances; unknowns b (3) and every c_s (3);
  nothing fixes the world frame, so a rigid motion of the base is invisible;
- ``plane`` (a touch on a plane): the ball centre lies on plane j, n_j . p = d_j with the
  ball's radius folded into d_j; unknowns b (3) and each plane (tilt 2, offset 1).

A :class:`Kind` builds those unknowns (``nuisance``) from a start tip pose, turns tip poses and
nuisance values into residuals [m], and into per-row errors (position [m], rotation [rad]) for
validation. Nuisance shared with the training rows (base, target, markers, spheres and planes
seen in training) is kept for held-out rows; a sphere or plane only held-out rows touch is
fitted on them (its centre / plane is not a robot parameter): :meth:`Kind.held_out_nuisance`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import from_vector, invert, kabsch, Rotation, skew

Array = NDArray[np.float64]
KINDS = ('spheres', 'points', 'pose', 'plane')
DEFAULT_ROTATION_WEIGHT = 1.0   # [m/rad]: 1 mrad counts as 1 mm
START_POSES = 24                # poses (evenly spread) for the closed-form start of a pose fit


def _rows(values: ArrayLike, shape_tail: tuple[int, ...], what: str, m: int) -> Array:
    a = np.array(values, dtype=float)
    if a.shape != (m,) + shape_tail or not np.all(np.isfinite(a)):
        raise ValueError(f'{what}: expected {m} finite rows of shape {shape_tail}, got '
                         f'{a.shape}')
    a.setflags(write=False)
    return a


def _ids(values: ArrayLike, what: str, m: int) -> Array:
    a = np.array(values)
    if a.shape != (m,) or not np.issubdtype(a.dtype, np.integer):
        raise ValueError(f'{what}: expected {m} integer ids, got {a.dtype} {a.shape}')
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class Measurements:
    """Joint angles q (m, n) [rad] and what was measured at them (see the module docstring).

    kind 'points': ``target`` (m,) marker id, ``values`` (m, 3) [m]; 'pose': ``values``
    (m, 4, 4) T_world_target (already inverted for a camera on the arm); 'spheres': ``target``
    sphere id, ``distances`` ((i, j, D [m]), ...); 'plane': ``target`` plane id.
    ``ball`` (3,) [m]: nominal ball / marker offset in the tip (spheres, plane, points start).
    """

    kind: str
    q: Array
    target: Array | None = None
    values: Array | None = None
    distances: tuple[tuple[int, int, float], ...] = ()
    ball: Array = field(default_factory=lambda: np.zeros(3))
    rotation_weight: float | None = DEFAULT_ROTATION_WEIGHT    # None: balanced on the data

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f'unknown measurement kind {self.kind!r}; use one of {KINDS}')
        q = np.array(self.q, dtype=float)
        if q.ndim != 2 or len(q) == 0 or not np.all(np.isfinite(q)):
            raise ValueError(f'q must be (m, n) finite joint angles [rad], got {q.shape}')
        q.setflags(write=False)
        object.__setattr__(self, 'q', q)
        m = len(q)
        if self.kind == 'pose':
            object.__setattr__(self, 'values', _rows(self.values, (4, 4), 'poses', m))
        else:
            object.__setattr__(self, 'target', _ids(
                np.zeros(m, int) if self.target is None else self.target, 'target ids', m))
        if self.kind == 'points':
            object.__setattr__(self, 'values', _rows(self.values, (3,), 'points', m))
        object.__setattr__(self, 'ball', _rows(self.ball, (), 'ball', 3))
        object.__setattr__(self, 'distances', tuple(
            (int(i), int(j), float(d)) for i, j, d in self.distances))
        if self.rotation_weight is not None and not self.rotation_weight > 0.0:
            raise ValueError(f'rotation_weight must be > 0 [m/rad], got {self.rotation_weight}')

    def __len__(self) -> int:
        return len(self.q)

    @property
    def has_rotation(self) -> bool:
        return self.kind == 'pose'

    def take(self, rows: ArrayLike) -> 'Measurements':
        """The measurements of ``rows`` (indices), distances kept where both spheres remain."""
        rows = np.asarray(rows, dtype=np.intp)
        target = None if self.target is None else self.target[rows]
        present = set() if target is None else {int(t) for t in target}
        return Measurements(self.kind, self.q[rows], target,
                            None if self.values is None else self.values[rows],
                            tuple(d for d in self.distances
                                  if d[0] in present and d[1] in present),
                            self.ball, self.rotation_weight)


def textbook_minimum(prismatic: ArrayLike, kind: str, markers: int = 1) -> int:
    """Minimal parameter count of a complete, minimal model of R revolute and P prismatic
    joints (``prismatic``: one flag per joint) with its base and tool frames (Everett, Mooring
    and Roth: 4 R + 2 P + 6), less what the measurement cannot see: a marker's orientation
    (points: 3; spheres and plane: 3 for the ball plus the 6 of the base, which the centres or
    planes absorb), plus 3 per further marker."""
    slides = int(np.count_nonzero(prismatic))
    complete = 4 * (len(prismatic) - slides) + 2 * slides + 6
    unseen = {'pose': 0, 'points': 3, 'spheres': 9, 'plane': 9}[kind]
    return complete - unseen + (3 * (markers - 1) if kind == 'points' else 0)


# --- the kinds: nuisance unknowns and residuals ----------------------------------------------

def _perturbed(T0: Array, d: Array) -> Array:
    return T0 @ from_vector(d)


def _rotation_errors(R_measured: Array, R_model: Array) -> Array:
    """(m, 3) rotation vectors of R_measured^T R_model [rad] (angles below pi)."""
    E = np.swapaxes(R_measured, 1, 2) @ R_model
    vee = np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]],
                   axis=1)
    s = 0.5 * np.linalg.norm(vee, axis=1)
    angle = np.arctan2(s, 0.5 * (np.trace(E, axis1=1, axis2=2) - 1.0))
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 1.0)
    return 0.5 * vee * scale[:, None]


class Kind:
    """Nuisance unknowns and residuals of one kind of measurement (module docstring).

    ``residuals`` gives ``per_row`` values for each row, in row order, each of its own row's tip
    pose only; any after those depend on no tip pose (the spheres' distances).
    """

    per_row = 0

    def __init__(self, data: Measurements, T_tip: Array) -> None:
        """Start values of the nuisance for ``data`` with start tip poses T_tip (m, 4, 4)."""
        self.data = data
        self.x0, self.names = self._start(T_tip)

    def _start(self, T_tip: Array) -> tuple[Array, tuple[str, ...]]:
        raise NotImplementedError

    def residuals(self, T_tip: Array, x: Array) -> Array:
        raise NotImplementedError

    def errors(self, T_tip: Array, x: Array, data: Measurements) -> tuple[Array, Array]:
        """Per row of ``data``: position error [m] and rotation error [rad] (nan: none)."""
        raise NotImplementedError

    def held_out_nuisance(self, T_tip: Array, x: Array,
                          data: Measurements) -> tuple['Kind', Array]:
        """(kind, nuisance) to evaluate ``data`` (held-out rows, tip poses T_tip) with
        nuisance ``x`` from training; spheres/planes only they touch are fitted on them
        (module docstring)."""
        return self, x

    @property
    def frame_dofs(self) -> int:
        """Nuisance unknowns counted by the textbook minimum (base and tool frames)."""
        raise NotImplementedError

    def gauge(self, T_tip: Array, x: Array) -> Array:
        """(residuals, g): directions in which the residual vector moves under a symmetry of
        the cost that no unknown spans (identifiability holds them fixed); none by default."""
        return np.empty((len(self.residuals(T_tip, x)), 0))

    def tip_derivatives(self, T_tip: Array, x: Array, step: float) -> Array:
        """(residuals, 6): d residuals / d a motion of every tip along the unit twists of the
        base frame (translation along x, y, z, rotation about x, y, z, as
        T_tip -> Exp(h e_j) T_tip); by central differences of ``step`` unless a kind knows
        them in closed form."""
        plus, minus = _unit_motions(step), _unit_motions(-step)
        return np.stack([(self.residuals(plus[j] @ T_tip, x)
                          - self.residuals(minus[j] @ T_tip, x)) / (2.0 * step)
                         for j in range(6)], axis=1)

    def nuisance_jacobian(self, T_tip: Array, x: Array, step: float) -> Array:
        """(residuals, len(x)) d residuals / d nuisance; by central differences of ``step``
        unless a kind knows it in closed form."""
        columns = []
        for k in range(len(x)):
            pair = []
            for h in (step, -step):
                moved = np.array(x, dtype=float)
                moved[k] += h
                pair.append(self.residuals(T_tip, moved))
            columns.append((pair[0] - pair[1]) / (2.0 * step))
        return np.stack(columns, axis=1) if columns else np.empty(
            (len(self.residuals(T_tip, x)), 0))


class PointsKind(Kind):
    per_row = 3

    def _start(self, T_tip):
        d = self.data
        self.markers = tuple(int(k) for k in np.unique(d.target))
        self.row_marker = np.searchsorted(self.markers, d.target)
        offsets = np.tile(d.ball, (len(self.markers), 1))
        base = np.eye(4)
        for _ in range(5):   # alternate: base by Kabsch, markers by linear least squares
            p_tip = np.einsum('mij,mj->mi', T_tip[:, :3, :3], offsets[self.row_marker]) \
                + T_tip[:, :3, 3]
            base = kabsch(p_tip, d.values)
            local = d.values @ base[:3, :3] - base[:3, :3].T @ base[:3, 3]   # in base
            r = np.einsum('mji,mj->mi', T_tip[:, :3, :3], local - T_tip[:, :3, 3])
            offsets = np.array([r[self.row_marker == k].mean(axis=0)
                                for k in range(len(self.markers))])
        self.base0 = base
        names = tuple(f'base_{c}' for c in ('x', 'y', 'z', 'rx', 'ry', 'rz')) + tuple(
            f'marker_{k}_{c}' for k in self.markers for c in 'xyz')
        return np.concatenate([np.zeros(6), offsets.ravel()]), names

    def _predict(self, T_tip, x, data):
        base = _perturbed(self.base0, x[:6])
        offsets = x[6:].reshape(-1, 3)[np.searchsorted(self.markers, data.target)]
        p = np.einsum('mij,mj->mi', T_tip[:, :3, :3], offsets) + T_tip[:, :3, 3]
        return p @ base[:3, :3].T + base[:3, 3]

    def residuals(self, T_tip, x):
        return (self._predict(T_tip, x, self.data) - self.data.values).ravel()

    def _in_base(self, T_tip, x):
        """(marker positions in the robot base (m, 3), R_world_base)."""
        offsets = x[6:].reshape(-1, 3)[self.row_marker]
        p = np.einsum('mij,mj->mi', T_tip[:, :3, :3], offsets) + T_tip[:, :3, 3]
        return p, self.base0[:3, :3] @ Rotation.from_rotvec(x[3:6]).as_matrix()

    def tip_derivatives(self, T_tip, x, step):
        """Closed form: a tip twist (v, w) in the robot base moves the marker by
        R_world_base (v - [p]x w)."""
        p, R = self._in_base(T_tip, x)
        return np.einsum('ab,mbj->maj', R, np.concatenate(
            [np.broadcast_to(np.eye(3), (len(p), 3, 3)), -skew(p)], axis=2)).reshape(-1, 6)

    def nuisance_jacobian(self, T_tip, x, step):
        """Closed form: T_world_base = base0 (Exp(w), t): d / d t = R0; d / d w = R0 (-[Exp(w)
        p]x) J_l(w) (J_l: SO(3)'s left Jacobian); d / d marker k = R_world_base R_tip on its
        rows."""
        p, R = self._in_base(T_tip, x)
        R0, m = self.base0[:3, :3], len(p)
        J = np.zeros((m, 3, len(x)))
        J[:, :, :3] = R0
        turned = p @ Rotation.from_rotvec(x[3:6]).as_matrix().T
        J[:, :, 3:6] = np.einsum('ab,mbc->mac', R0, -skew(turned)) @ _left_jacobian(x[3:6])
        on_tip = np.einsum('ab,mbc->mac', R, T_tip[:, :3, :3])
        for k in range(len(self.markers)):
            rows = self.row_marker == k
            J[rows, :, 6 + 3 * k:9 + 3 * k] = on_tip[rows]
        return J.reshape(3 * m, len(x))

    def errors(self, T_tip, x, data):
        unknown = set(int(t) for t in data.target) - set(self.markers)
        if unknown:
            raise ValueError(f'markers {sorted(unknown)} have no training rows')
        e = np.linalg.norm(self._predict(T_tip, x, data) - data.values, axis=1)
        return e, np.full(len(e), np.nan)

    @property
    def frame_dofs(self):
        return 6 + 3 * len(self.markers)


class PoseKind(Kind):
    per_row = 6

    def _start(self, T_tip):
        d = self.data
        if len(d) >= 3:
            from cobot_calib_ros.core.landmarks.hand_eye import park_martin  # (pulls cv2)
            some = np.unique(np.linspace(0, len(d) - 1, START_POSES).astype(int))
            target = park_martin(T_tip[some], invert_all(d.values[some]))   # T_tip_target
        else:
            target = np.eye(4)
        base = _mean_pose(d.values @ invert_all(T_tip @ target))
        self.base0, self.target0 = base, target
        names = tuple(f'{f}_{c}' for f in ('base', 'target')
                      for c in ('x', 'y', 'z', 'rx', 'ry', 'rz'))
        return np.zeros(12), names

    def _predict(self, T_tip, x):
        return _perturbed(self.base0, x[:6]) @ T_tip @ _perturbed(self.target0, x[6:12])

    def residuals(self, T_tip, x):
        T = self._predict(T_tip, x)
        dp = T[:, :3, 3] - self.data.values[:, :3, 3]
        dr = _rotation_errors(self.data.values[:, :3, :3], T[:, :3, :3])
        weight = self.data.rotation_weight or DEFAULT_ROTATION_WEIGHT   # None: not yet balanced
        return np.hstack([dp, weight * dr]).ravel()

    def errors(self, T_tip, x, data):
        T = self._predict(T_tip, x)
        return (np.linalg.norm(T[:, :3, 3] - data.values[:, :3, 3], axis=1),
                np.linalg.norm(_rotation_errors(data.values[:, :3, :3], T[:, :3, :3]), axis=1))

    @property
    def frame_dofs(self):
        return 12


class SpheresKind(Kind):
    per_row = 3

    def _start(self, T_tip):
        d = self.data
        self.spheres = tuple(int(s) for s in np.unique(d.target))
        self.row_sphere = np.searchsorted(self.spheres, d.target)
        few = [s for s in self.spheres if np.sum(d.target == s) < 2]
        if few:
            raise ValueError(f'spheres {few} have fewer than 2 rows: a centre needs at least 2')
        self.dist = [(self.spheres.index(i), self.spheres.index(j), D)
                     for i, j, D in d.distances]
        self.sqrt_w = math.sqrt(len(d))       # a distance weighs as m rows: it holds the scale
        p = _ball(T_tip, d.ball)
        centres = np.array([p[self.row_sphere == k].mean(axis=0)
                            for k in range(len(self.spheres))])
        names = tuple(f'ball_{c}' for c in 'xyz') + tuple(
            f'centre_{s}_{c}' for s in self.spheres for c in 'xyz')
        return np.concatenate([d.ball, centres.ravel()]), names

    def residuals(self, T_tip, x):
        centres = x[3:].reshape(-1, 3)
        r = (_ball(T_tip, x[:3]) - centres[self.row_sphere]).ravel()
        gaps = [self.sqrt_w * (np.linalg.norm(centres[a] - centres[b]) - D)
                for a, b, D in self.dist]
        return np.concatenate([r, gaps])

    def tip_derivatives(self, T_tip, x, step):
        """Closed form: the ball p = R b + t moves by v + w x p = v - [p]x w."""
        p = _ball(T_tip, x[:3])
        D = np.zeros((len(self.residuals(T_tip, x)), 6))
        tied = 3 * len(p)
        D[:tied, :3] = np.tile(np.eye(3), (len(p), 1))
        D[:tied, 3:] = -skew(p).reshape(-1, 3)
        return D

    def nuisance_jacobian(self, T_tip, x, step):
        """Closed form: d (p_i - c_s) / d b = R_i, / d c_s = -I; a distance row sqrt(w) u,
        u the unit vector between its centres."""
        m, S = len(T_tip), len(self.spheres)
        J = np.zeros((3 * m + len(self.dist), 3 + 3 * S))
        J[:3 * m, :3] = T_tip[:, :3, :3].reshape(-1, 3)
        rows = np.arange(3 * m)
        J[rows, 3 + 3 * np.repeat(self.row_sphere, 3) + rows % 3] = -1.0
        centres = x[3:].reshape(-1, 3)
        for k, (a, b, _) in enumerate(self.dist):
            gap = centres[a] - centres[b]
            u = self.sqrt_w * gap / np.linalg.norm(gap)
            J[3 * m + k, 3 + 3 * a:6 + 3 * a] += u
            J[3 * m + k, 3 + 3 * b:6 + 3 * b] -= u
        return J

    def gauge(self, T_tip, x):
        """A rotation of the base, the centres turned with it, turns every residual p - c
        (the cost is invariant; the residual vector is not, away from zero residuals):
        columns w x r = -[r]x w. Translations are the centres' own columns."""
        centres = x[3:].reshape(-1, 3)
        r = _ball(T_tip, x[:3]) - centres[self.row_sphere]
        return np.vstack([-skew(r).reshape(-1, 3), np.zeros((len(self.dist), 3))])

    def held_out_nuisance(self, T_tip, x, data):
        kind = _HeldOutSpheres(self, T_tip, x, data)
        return kind, kind.x0

    def errors(self, T_tip, x, data):
        centres = x[3:].reshape(-1, 3)[np.searchsorted(self.spheres, data.target)]
        e = np.linalg.norm(_ball(T_tip, x[:3]) - centres, axis=1)
        return e, np.full(len(e), np.nan)

    @property
    def frame_dofs(self):
        return 3


class _HeldOutSpheres(SpheresKind):
    """Training centres where known; the centroid of the held-out balls elsewhere."""

    def __init__(self, trained: SpheresKind, T_tip, x, data):
        self.data = data
        p = _ball(T_tip, x[:3])
        known = dict(zip(trained.spheres, x[3:].reshape(-1, 3)))
        self.spheres = tuple(int(s) for s in np.unique(data.target))
        centres = [known[s] if s in known else p[data.target == s].mean(axis=0)
                   for s in self.spheres]
        self.x0 = np.concatenate([x[:3], np.ravel(centres)])
        self.names = ()


class PlaneKind(Kind):
    per_row = 1

    def _start(self, T_tip):
        d = self.data
        self.planes = tuple(int(s) for s in np.unique(d.target))
        self.row_plane = np.searchsorted(self.planes, d.target)
        p = _ball(T_tip, d.ball)
        self.frames0 = []
        for k in range(len(self.planes)):
            pts = p[self.row_plane == k]
            if len(pts) < 3:
                raise ValueError(f'plane {self.planes[k]} has {len(pts)} rows: a plane needs '
                                 'at least 3')
            self.frames0.append(_plane_frame(pts))
        names = tuple(f'ball_{c}' for c in 'xyz') + tuple(
            f'plane_{s}_{c}' for s in self.planes for c in ('tilt_x', 'tilt_y', 'offset'))
        return np.concatenate([d.ball, np.zeros(3 * len(self.planes))]), names

    def _distances(self, T_tip, x, data, frames0, planes):
        p = _ball(T_tip, x[:3])
        row = np.searchsorted(planes, data.target)
        out = np.empty(len(p))
        for k, (n0, c0) in enumerate(frames0):
            a, b, off = x[3 + 3 * k: 6 + 3 * k]
            n = Rotation.from_rotvec(n0[1] * a + n0[2] * b).apply(n0[0])
            mask = row == k
            out[mask] = (p[mask] - c0) @ n - off
        return out

    def residuals(self, T_tip, x):
        return self._distances(T_tip, x, self.data, self.frames0, self.planes)

    def errors(self, T_tip, x, data):
        e = np.abs(self._distances(T_tip, x, data, self.frames0, self.planes))
        return e, np.full(len(e), np.nan)

    def held_out_nuisance(self, T_tip, x, data):
        new = [int(s) for s in np.unique(data.target) if int(s) not in self.planes]
        if not new:
            return self, x
        kind = PlaneKind.__new__(PlaneKind)
        kind.data = data
        kind.planes = tuple(sorted(set(self.planes) | set(new)))
        p = _ball(T_tip, x[:3])
        frames, values = [], [x[:3]]
        for s in kind.planes:
            if s in self.planes:
                k = self.planes.index(s)
                frames.append(self.frames0[k])
                values.append(x[3 + 3 * k: 6 + 3 * k])
            else:
                frames.append(_plane_frame(p[data.target == s]))
                values.append(np.zeros(3))
        kind.frames0, kind.x0, kind.names = frames, np.concatenate(values), ()
        return kind, kind.x0

    @property
    def frame_dofs(self):
        return 3


KIND_CLASSES = {'points': PointsKind, 'pose': PoseKind, 'spheres': SpheresKind,
                'plane': PlaneKind}


def make_kind(data: Measurements, T_tip: Array) -> Kind:
    return KIND_CLASSES[data.kind](data, T_tip)


def _left_jacobian(w: Array) -> Array:
    """(3, 3) SO(3)'s left Jacobian: Exp(w + dw) = Exp(J_l(w) dw) Exp(w) to first order."""
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-6:
        return np.eye(3) + W / 2.0 + W @ W / 6.0
    return (np.eye(3) + (1.0 - math.cos(theta)) / theta ** 2 * W
            + (theta - math.sin(theta)) / theta ** 3 * W @ W)


def _unit_motions(h: float) -> Array:
    """(6, 4, 4) Exp(h e_j): translations by h along x, y, z, rotations by h about x, y, z."""
    c, s = math.cos(h), math.sin(h)
    motions = np.tile(np.eye(4), (6, 1, 1))
    for axis in range(3):
        motions[axis, axis, 3] = h
        j, k = (axis + 1) % 3, (axis + 2) % 3
        R = motions[3 + axis]
        R[j, j], R[j, k], R[k, j], R[k, k] = c, -s, s, c
    return motions


def _ball(T_tip: Array, b: Array) -> Array:
    return T_tip[:, :3, :3] @ np.asarray(b, dtype=float) + T_tip[:, :3, 3]


def _plane_frame(points: Array) -> tuple[Array, Array]:
    """((normal, u, v), centroid) of the least-squares plane through points (k, 3)."""
    c = points.mean(axis=0)
    _, _, Vt = np.linalg.svd(points - c)
    return np.array([Vt[2], Vt[0], Vt[1]]), c


def invert_all(T: Array) -> Array:
    """Inverse of every (4, 4) in a stack (m, 4, 4)."""
    return np.stack([invert(t) for t in T])


def _mean_pose(T: Array) -> Array:
    """Average of poses (m, 4, 4): mean translation, chordal mean rotation."""
    R = Rotation.from_matrix(T[:, :3, :3]).mean().as_matrix()
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, T[:, :3, 3].mean(axis=0)
    return out
