"""Checking a calibration against absolute measurements, and reporting it as in the paper.

:func:`error_stats` gives the paper's Table 5 columns, :func:`table6` its Table 6 layout.
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import apply
from cobot_calib_ros.core.kinematics.identification.parameters import tool_frames
from cobot_calib_ros.core.kinematics.model import KinematicModel
from cobot_calib_ros.core.frames import kabsch

Array = NDArray[np.float64]


def error_stats(errors_m: ArrayLike) -> dict[str, float]:
    """mean_m, std_m (population), min_m, max_m of position errors [m] (the paper's Table 5
    columns; a report prints them in mm)."""
    e = np.asarray(errors_m, dtype=float).ravel()
    if e.size == 0 or not np.all(np.isfinite(e)):
        raise ValueError('error_stats needs at least one finite error')
    return {'mean_m': float(e.mean()), 'std_m': float(e.std()),
            'min_m': float(e.min()), 'max_m': float(e.max())}


def register_rigid(p_model: ArrayLike, p_measured: ArrayLike) -> Array:
    """(4, 4) least-squares rigid T_world_base (Kabsch): p_measured ~ T @ p_model.

    p_model (m, 3) [m] in the robot base frame, p_measured (m, 3) [m] in the world (tracker)
    frame, m >= 3 points not all on one line.
    """
    pm = np.asarray(p_model, dtype=float)
    pw = np.asarray(p_measured, dtype=float)
    if pm.shape != pw.shape or pm.ndim != 2 or pm.shape[1] != 3 or len(pm) < 3:
        raise ValueError(f'need two (m, 3) point sets with m >= 3, got {pm.shape} and {pw.shape}')
    return kabsch(pm, pw)


def absolute_errors(model: KinematicModel, params: ArrayLike, p_flange_tool: ArrayLike,
                    q: ArrayLike, p_measured: ArrayLike,
                    T_world_base: ArrayLike | None = None) -> Array:
    """(m,) distances [m] between modelled and measured tool positions (the paper's eq 13).

    q (m, n) [rad], p_measured (m, 3) [m] in the world frame. When ``T_world_base`` is None it
    is fitted here (:func:`register_rigid`): a relative (sphere) calibration identifies no
    world frame, so comparing it with a tracker needs this best-fit registration, which absorbs
    6 dof of the error (report that alongside the figures).
    """
    p_model = tool_frames(model, params, p_flange_tool, q)[:, :3, 3]
    pw = np.asarray(p_measured, dtype=float)
    T = register_rigid(p_model, pw) if T_world_base is None else np.asarray(T_world_base)
    return np.linalg.norm(apply(T, p_model) - pw, axis=1)


def table6(model: KinematicModel, params: ArrayLike) -> str:
    """Parameter table as the paper's Table 6: lengths in mm (6 decimals), angles in rad.

    MDH: one line per joint row i = 1..n with alpha_{i-1} [rad], a_{i-1} [mm], theta_i [rad],
    d_i [mm] (the paper numbers these rows 0..n-1). Origin models: joint name, x, y, z [mm],
    roll, pitch, yaw [rad].
    """
    rows = model.rows(params)
    if model.kind == 'mdh':
        header = f'{"i":>2} {"alpha [rad]":>12} {"a [mm]":>14} {"theta [rad]":>12} {"d [mm]":>14}'
        lines = [f'{i:>2} {r[0]:>12.6f} {r[1] * 1e3:>14.6f} {r[2]:>12.6f} {r[3] * 1e3:>14.6f}'
                 for i, r in enumerate(rows, start=1)]
    else:
        width = max(len(n) for n in model.joint_names)
        header = (f'{"joint":<{width}} ' + ' '.join(f'{c:>14}' for c in
                  ('x [mm]', 'y [mm]', 'z [mm]')) + ' '
                  + ' '.join(f'{c:>12}' for c in ('roll [rad]', 'pitch [rad]', 'yaw [rad]')))
        lines = [f'{n:<{width}} ' + ' '.join(f'{v * 1e3:>14.6f}' for v in r[:3]) + ' '
                 + ' '.join(f'{v:>12.6f}' for v in r[3:])
                 for n, r in zip(model.joint_names, rows)]
    return '\n'.join([header] + lines)
