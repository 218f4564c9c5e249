"""d residuals / d model parameters of a measurement, through the tip pose (measurement_fit).

A model parameter or a joint offset moves the tip rigidly: T_tip -> Exp(h [xi]) T_tip to first
order, xi = (v, w) its twist in the base frame (:func:`model.parameter_twists`). A kind's
residuals of row i depend on row i's tip pose alone (``Kind.per_row`` of them, row after row,
then those of no tip pose: the spheres' distances), so

    J[r, k] = sum_j D[r, j] xi_k[row(r), j],

D[:, j] the residuals' derivative when every tip moves along the j-th unit twist (translation
along x, y, z, rotation about x, y, z of the base frame): 6 central differences, however many
parameters. Differencing each parameter instead cost two forward kinematics and two residual
evaluations per parameter (10,000 tracker points: most of a 160 s identification).
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.kinematics.identification.measurements import Kind
from cobot_calib_ros.core.kinematics.model import KinematicModel, parameter_twists

Array = NDArray[np.float64]


def tip_twists(model: KinematicModel, params: Array, offsets: Array, names: tuple[str, ...],
               q: Array) -> Array:
    """(len(names), m, 6) twists of the named parameters (model parameter names, or
    ``offset_<joint>``: q_model = q + offset) at ``params`` (P,), joint ``offsets`` (n,)."""
    twists, joints = parameter_twists(model, params, q + offsets)
    rows = [joints[model.joint_names.index(n[7:])] if n.startswith('offset_')
            else twists[model.parameter_names.index(n)] for n in names]
    return np.stack(rows) if rows else np.empty((0, len(q), 6))


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


def residual_jacobian(kind: Kind, T_tip: Array, nuisance: Array, twists: Array,
                      step: float) -> Array:
    """(N, K) d kind.residuals(T_tip, nuisance) / d parameters whose tip twists are
    ``twists`` (K, m, 6); central differences of ``step`` [m, rad] along the unit twists."""
    plus, minus = _unit_motions(step), _unit_motions(-step)
    D = np.stack([(kind.residuals(plus[j] @ T_tip, nuisance)
                   - kind.residuals(minus[j] @ T_tip, nuisance)) / (2.0 * step)
                  for j in range(6)], axis=1)
    K, m = twists.shape[:2]
    tied = m * kind.per_row
    J = np.zeros((len(D), K))
    J[:tied] = np.einsum('mrj,kmj->mrk', D[:tied].reshape(m, kind.per_row, 6),
                         twists).reshape(tied, K)
    return J
