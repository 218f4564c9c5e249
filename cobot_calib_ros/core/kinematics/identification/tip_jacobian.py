"""d residuals / d model parameters of a measurement, through the tip pose (measurement_fit).

A model parameter or a joint offset moves the tip rigidly: T_tip -> Exp(h [xi]) T_tip to first
order, xi = (v, w) its twist in the base frame (:func:`model.parameter_twists`). A kind's
residuals of row i depend on row i's tip pose alone (``Kind.per_row`` of them, row after row,
then those of no tip pose: the spheres' distances), so

    J[r, k] = sum_j D[r, j] xi_k[row(r), j],

D[:, j] the residuals' derivative when every tip moves along the j-th unit twist (translation
along x, y, z, rotation about x, y, z of the base frame): the kind's closed form (spheres) or
6 central differences, however many parameters. Differencing each parameter instead cost two forward kinematics and two residual
evaluations per parameter (10,000 tracker points: most of a 160 s identification).
"""
from __future__ import annotations

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


def residual_jacobian(kind: Kind, T_tip: Array, nuisance: Array, twists: Array,
                      step: float) -> Array:
    """(N, K) d kind.residuals(T_tip, nuisance) / d parameters whose tip twists are
    ``twists`` (K, m, 6), through the kind's derivatives along the unit twists
    (:meth:`Kind.tip_derivatives`: closed form, or central differences of ``step`` [m, rad])."""
    D = kind.tip_derivatives(T_tip, nuisance, step)
    K, m = twists.shape[:2]
    tied = m * kind.per_row
    J = np.zeros((len(D), K))
    J[:tied] = np.einsum('mrj,kmj->mrk', D[:tied].reshape(m, kind.per_row, 6),
                         twists).reshape(tied, K)
    return J
