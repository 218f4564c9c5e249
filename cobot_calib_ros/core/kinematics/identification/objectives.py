"""Least-squares residuals of the calibration data, with analytic Jacobians.

Every objective has unknowns ``x = [free parameters..., nuisance...]``, ``x0`` (start),
``residuals(x)`` (N,) [m], ``jacobian(x)`` (N, len(x)) and ``solution(x)`` -> (params,
tool_xyz, extra). Three forms:

- :class:`CentresObjective` (relative, default): the sphere centres c_s in the base frame are
  nuisance unknowns; residuals p_i - c_sphere(i) (3 per row), then
  sqrt(w) (||c_a - c_b|| - D_ab) per known distance.
- :class:`PairsObjective` (relative, the paper's eq 11 on chosen row pairs): same sphere ->
  p_i - p_j (3); spheres a != b with a known distance -> ||p_i - p_j|| - D_ab (1). Both are
  independent of the base/world frame, so there are no nuisance unknowns. Where the pairs
  hold every pair of a sphere's rows, those n(n-1)/2 difference residuals are replaced by the
  n residuals sqrt(n) (p_i - mean p): the same sum of squares, gradient and Gauss-Newton
  matrix (sum_{i<j} |p_i - p_j|^2 = n sum_i |p_i - mean p|^2), 3n rows instead of
  3n(n-1)/2 (a robust loss then weighs rows instead of pairs).
- :class:`AbsoluteObjective` (laser tracker): residuals T_world_base p_i - p_measured,i (3 per
  row) with the 6-dof T_world_base as nuisance, T = (Exp(w) R0, t), R0 from a rigid fit of the
  start model to the measurements, x holding (t [m], w [rad]).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core.frames import make_transform
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import ParameterSet
from cobot_calib_ros.core.kinematics.identification.validation import register_rigid
from cobot_calib_ros.core.frames import skew

Array = NDArray[np.float64]


class _FreeKinematics:
    """Tool positions (m, 3) and d p / d free (m, 3, F) at free values x, cached for the last x
    (the solver asks for residuals and Jacobian at the same point; Nelder-Mead only for
    positions, which cost a fraction of the Jacobian)."""

    def __init__(self, parameter_set: ParameterSet, q: Array, params0: Array,
                 tool_xyz0: Array) -> None:
        self.parameter_set, self.q = parameter_set, q
        self.params0, self.tool_xyz0 = params0, tool_xyz0
        self.x0 = parameter_set.values(params0, tool_xyz0)
        self._p_key = self._J_key = b''
        self._p, self._J = np.empty((0, 3)), np.empty((0, 3, 0))

    def full(self, x_free: Array) -> tuple[Array, Array]:
        """(params, tool_xyz) with the free ones from x_free."""
        return self.parameter_set.assign(x_free, self.params0, self.tool_xyz0)

    def positions(self, x_free: Array) -> Array:
        key = np.asarray(x_free, dtype=float).tobytes()
        if key != self._p_key:
            self._p = self.parameter_set.positions(*self.full(x_free), self.q)
            self._p_key = key
        return self._p

    def __call__(self, x_free: Array) -> tuple[Array, Array]:
        """Positions and Jacobian."""
        key = np.asarray(x_free, dtype=float).tobytes()
        if key != self._J_key:
            self._p, self._J = self.parameter_set.positions_and_jacobian(
                *self.full(x_free), self.q)
            self._p_key = self._J_key = key
        return self._p, self._J


class CentresObjective:
    """Relative data, sphere centres as nuisance unknowns (see the module docstring).

    ``distance_weight`` w (default: the number of rows m) weights each known-distance residual
    as if the distance were measured sqrt(w) times more precisely than one coupling. With m, the
    distance keeps its hold on the scale however many poses are added; with noise-free data any
    w > 0 gives the same minimum.
    """

    objective, form = 'relative', 'centres'

    def __init__(self, parameter_set: ParameterSet, observations: SphereObservations,
                 params0: Array, tool_xyz0: Array, distance_weight: float | None = None) -> None:
        self.kin = _FreeKinematics(parameter_set, observations.q, params0, tool_xyz0)
        self.n_free = len(parameter_set.free)
        self.spheres = observations.spheres
        self.row_sphere = np.searchsorted(self.spheres, observations.sphere)
        d = observations.known_distances
        self.dist_a = np.array([self.spheres.index(i) for i, _, _ in d], dtype=np.intp)
        self.dist_b = np.array([self.spheres.index(j) for _, j, _ in d], dtype=np.intp)
        self.dist = np.array([D for _, _, D in d], dtype=float)
        weight = len(observations.q) if distance_weight is None else float(distance_weight)
        if not weight > 0.0:
            raise ValueError(f'distance_weight must be > 0, got {distance_weight}')
        self.sqrt_w = math.sqrt(weight)
        p0 = self.kin.positions(self.kin.x0)
        self.x0 = np.concatenate([self.kin.x0, self._mean_per_sphere(p0).ravel()])
        self.nuisance_names = tuple(f'centre_{s}_{c}' for s in self.spheres for c in 'xyz')
        self.residual_count = 3 * len(p0) + len(self.dist)

    def _mean_per_sphere(self, p: Array) -> Array:
        sums = np.zeros((len(self.spheres), 3))
        np.add.at(sums, self.row_sphere, p)
        return sums / np.bincount(self.row_sphere)[:, None]

    def _split(self, x: Array) -> tuple[Array, Array]:
        return x[:self.n_free], x[self.n_free:].reshape(-1, 3)

    def residuals(self, x: Array) -> Array:
        x_free, centres = self._split(x)
        p = self.kin.positions(x_free)
        gap = centres[self.dist_a] - centres[self.dist_b]
        return np.concatenate([(p - centres[self.row_sphere]).ravel(),
                               self.sqrt_w * (np.linalg.norm(gap, axis=1) - self.dist)])

    def jacobian(self, x: Array) -> Array:
        x_free, centres = self._split(x)
        _, Jp = self.kin(x_free)
        m, F = len(Jp), self.n_free
        J = np.zeros((self.residual_count, len(x)))
        J[:3 * m, :F] = Jp.reshape(3 * m, F)
        rows = np.arange(3 * m)
        J[rows, F + 3 * np.repeat(self.row_sphere, 3) + rows % 3] = -1.0
        gap = centres[self.dist_a] - centres[self.dist_b]
        u = self.sqrt_w * gap / np.linalg.norm(gap, axis=1)[:, None]
        for k, (a, b) in enumerate(zip(self.dist_a, self.dist_b)):
            J[3 * m + k, F + 3 * a:F + 3 * a + 3] += u[k]
            J[3 * m + k, F + 3 * b:F + 3 * b + 3] -= u[k]
        return J

    def solution(self, x: Array) -> tuple[Array, Array, dict]:
        x_free, centres = self._split(x)
        params, tool = self.kin.full(x_free)
        return params, tool, {'sphere_centres_base': dict(zip(self.spheres, centres.copy()))}


def all_pairs(rows: ArrayLike) -> NDArray[np.intp]:
    """(k, 2) every unordered pair of the given row indices (the paper: all pairs of 300)."""
    r = np.asarray(rows, dtype=np.intp)
    i, j = np.triu_indices(len(r), k=1)
    return np.column_stack([r[i], r[j]])


class PairsObjective:
    """Relative data on row pairs, the paper's eq 11 (see the module docstring).

    Pairs between two spheres without a known distance carry no frame-free information and are
    skipped; ``extra`` counts them. ValueError when no pair is usable.
    """

    objective, form = 'relative', 'pairs'

    def __init__(self, parameter_set: ParameterSet, observations: SphereObservations,
                 params0: Array, tool_xyz0: Array, pairs: ArrayLike) -> None:
        m = len(observations.q)
        pairs = np.asarray(pairs)
        if (pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer)
                or len(pairs) == 0):
            raise ValueError(f'pairs must be a (k, 2) integer array of row indices, got '
                             f'{pairs.dtype} {pairs.shape}')
        if pairs.min() < 0 or pairs.max() >= m or np.any(pairs[:, 0] == pairs[:, 1]):
            raise ValueError(f'pairs must join two different rows in [0, {m})')
        self.kin = _FreeKinematics(parameter_set, observations.q, params0, tool_xyz0)
        self.n_free = len(parameter_set.free)
        s = observations.sphere[pairs]
        known = {}
        for a, b, D in observations.known_distances:
            known[(a, b)] = known[(b, a)] = D
        cross_D = np.array([known.get((a, b), np.nan) for a, b in s], dtype=float)
        same = s[:, 0] == s[:, 1]
        cross = ~same & np.isfinite(cross_D)
        self.same, self.cross, self.cross_D = pairs[same], pairs[cross], cross_D[cross]
        self.same_count = len(self.same)
        self.groups = []    # rows of spheres whose every pair is given: centroid residuals
        for sphere in np.unique(s[same, 0]):
            on_sphere = self.same[s[same, 0] == sphere]
            rows = np.unique(on_sphere)
            n = len(rows)
            unique_pairs = np.unique(np.sort(on_sphere, axis=1), axis=0)
            if n > 1 and len(unique_pairs) == len(on_sphere) == n * (n - 1) // 2:
                self.groups.append(rows)
        grouped = np.concatenate(self.groups) if self.groups else np.empty(0, np.intp)
        self.same = self.same[~np.isin(self.same[:, 0], grouped)]
        self.skipped = int(len(pairs) - same.sum() - cross.sum())
        if not self.same_count and not len(self.cross):
            raise ValueError('no usable pair: give pairs on the same sphere or between spheres '
                             'with a known distance')
        self._cross_columns = np.hstack([3 * self.cross[:, :1] + np.arange(3),
                                         3 * self.cross[:, 1:] + np.arange(3)]).ravel()
        self._cross_rows = np.arange(0, 6 * len(self.cross) + 1, 6)
        self.x0 = self.kin.x0
        self.nuisance_names: tuple[str, ...] = ()
        # a group of n rows holds 3 (n - 1) independent differences
        self.residual_count = 3 * (len(self.same) + len(grouped) - len(self.groups)) \
            + len(self.cross)

    def _centred(self, values: Array) -> list[Array]:
        """sqrt(n) (v_i - mean v) over each complete group's rows, flattened per group."""
        out = []
        for rows in self.groups:
            v = values[rows]
            out.append((math.sqrt(len(rows)) * (v - v.mean(axis=0))).reshape(-1, *v.shape[2:]))
        return out

    def residuals(self, x: Array) -> Array:
        p = self.kin.positions(x)
        d_same = p[self.same[:, 0]] - p[self.same[:, 1]]
        d_cross = p[self.cross[:, 0]] - p[self.cross[:, 1]]
        return np.concatenate([*(c.ravel() for c in self._centred(p)), d_same.ravel(),
                               np.linalg.norm(d_cross, axis=1) - self.cross_D])

    def jacobian(self, x: Array) -> Array:
        p, Jp = self.kin(x)
        J_groups = [c.reshape(-1, self.n_free) for c in self._centred(Jp)]
        J_same = (Jp[self.same[:, 0]] - Jp[self.same[:, 1]]).reshape(-1, self.n_free)
        d_cross = p[self.cross[:, 0]] - p[self.cross[:, 1]]
        u = d_cross / np.linalg.norm(d_cross, axis=1)[:, None]
        # u_k . (J_i - J_j) for every pair as one sparse product (6 entries a row): gathering
        # the (k, 3, F) blocks took 80 % of a solve on the paper's 44,850 pairs
        pick = sparse.csr_matrix((np.hstack([u, -u]).ravel(), self._cross_columns,
                                  self._cross_rows), shape=(len(u), Jp.shape[0] * 3))
        J_cross = pick @ Jp.reshape(-1, self.n_free)
        return np.concatenate([*J_groups, J_same, J_cross])

    def solution(self, x: Array) -> tuple[Array, Array, dict]:
        params, tool = self.kin.full(x)
        return params, tool, {'pairs_same_sphere': self.same_count,
                              'pairs_known_distance': len(self.cross),
                              'pairs_skipped': self.skipped}


def _left_jacobian_so3(w: Array) -> Array:
    """(3, 3) left Jacobian of SO(3): Exp(w + dw) = Exp(J_l(w) dw) Exp(w) to first order."""
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-6:
        return np.eye(3) + W / 2.0 + W @ W / 6.0
    return (np.eye(3) + (1.0 - math.cos(theta)) / theta ** 2 * W
            + (theta - math.sin(theta)) / theta ** 3 * W @ W)


class AbsoluteObjective:
    """Measured positions in a tracker (world) frame, T_world_base as nuisance (module doc)."""

    objective = form = 'absolute'

    def __init__(self, parameter_set: ParameterSet, observations: PositionObservations,
                 params0: Array, tool_xyz0: Array) -> None:
        if len(observations.q) < 3:
            raise ValueError(f'absolute data need at least 3 rows to place the world frame, '
                             f'got {len(observations.q)}: measure more configurations')
        self.kin = _FreeKinematics(parameter_set, observations.q, params0, tool_xyz0)
        self.n_free = len(parameter_set.free)
        self.p_measured = observations.p
        p0 = self.kin.positions(self.kin.x0)
        T0 = register_rigid(p0, self.p_measured)
        self.R0 = T0[:3, :3]
        self.x0 = np.concatenate([self.kin.x0, T0[:3, 3], np.zeros(3)])
        self.nuisance_names = ('base_x', 'base_y', 'base_z', 'base_wx', 'base_wy', 'base_wz')
        self.residual_count = 3 * len(p0)

    def _base(self, x: Array) -> tuple[Array, Array, Array]:
        """R_world_base, t_world_base, w of x."""
        t, w = x[self.n_free:self.n_free + 3], x[self.n_free + 3:]
        return Rotation.from_rotvec(w).as_matrix() @ self.R0, t, w

    def residuals(self, x: Array) -> Array:
        p = self.kin.positions(x[:self.n_free])
        R, t, _ = self._base(x)
        return (p @ R.T + t - self.p_measured).ravel()

    def jacobian(self, x: Array) -> Array:
        p, Jp = self.kin(x[:self.n_free])
        R, _, w = self._base(x)
        m = len(p)
        J_free = np.einsum('ac,icf->iaf', R, Jp)
        J_t = np.broadcast_to(np.eye(3), (m, 3, 3))
        # d (Exp(w) v) / dw = -[Exp(w) v]x J_l(w), v = R0 p
        Jl = _left_jacobian_so3(w)
        J_w = -np.cross((p @ R.T)[:, None, :], Jl.T[None, :, :]).transpose(0, 2, 1)
        return np.concatenate([J_free, J_t, J_w], axis=2).reshape(3 * m, -1)

    def solution(self, x: Array) -> tuple[Array, Array, dict]:
        params, tool = self.kin.full(x[:self.n_free])
        R, t, _ = self._base(x)
        return params, tool, {'T_world_base': make_transform(R, t)}
