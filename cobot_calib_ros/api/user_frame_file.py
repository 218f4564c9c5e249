"""A user frame measured offline (`cobot-calib user-frame --points FILE`): named reference points
touched with the robot's tool (their joints, read off the pendant) or measured by a laser tracker
(their positions, in the base or in the tracker's frame with the base's registration), fitted,
gated, stored and made active with the same fits and gate as the calibrate_user_frame service
(core.user_frame.calibrate, store.records.UserFrameRecord), with no suite running.

Points file: CSV with a header, one point per row: ``name``, ``user_x``, ``user_y``, ``user_z``
(the point in the user frame, its drawing [m]) and either the chain's joint names (the joints
when the tool centre touched the point [rad]: mapped through the active kinematics and TCP) or
``x``, ``y``, ``z`` (the point measured [m], in the base, or in the tracker frame with
``T_base_tracker``).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import io
from pathlib import Path
import time

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal

USER = ('user_x', 'user_y', 'user_z')
MEASURED = ('x', 'y', 'z')
MAX_RMS_ERROR = 1.0e-3      # [m] as user_frame_solver's max_rms_error parameter's default


@dataclass(frozen=True)
class Points:
    """A points file read: names, user-frame points (N, 3) [m], and either joints (N, n) [rad]
    or measured points (N, 3) [m] (the other None)."""

    names: list[str]
    p_user: np.ndarray
    joints: np.ndarray | None
    measured: np.ndarray | None


def read_points(path: str | Path, joint_names) -> Points:
    """The points file at ``path`` (module doc); ValueError naming the file, line and column."""
    path = Path(path).expanduser()
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f'--points {path}: cannot read ({e})') from None
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f'--points {path}: empty; expected a header name,user_x,user_y,user_z '
                         'and the joints or x,y,z')
    header = [h.strip() for h in rows[0]]
    missing = [c for c in ('name', *USER) if c not in header]
    if missing:
        raise ValueError(f'--points {path}: missing columns {missing}; the header has {header}')
    joints = [j for j in joint_names if j in header]
    if all(c in header for c in MEASURED):
        columns, touched = MEASURED, False
    elif len(joints) == len(joint_names):
        columns, touched = tuple(joint_names), True
    else:
        raise ValueError(f'--points {path}: give the measured x,y,z [m] or the joints '
                         f'{list(joint_names)} [rad] of each point; the header has {header}')
    names, values = [], []
    for line, row in enumerate(rows[1:], start=2):
        cells = dict(zip(header, (c.strip() for c in row)))
        try:
            values.append([float(cells[c]) for c in (*USER, *columns)])
        except (KeyError, ValueError):
            raise ValueError(f'--points {path}:{line}: expected numbers in {[*USER, *columns]}, '
                             f'got {row}') from None
        names.append(cells['name'] or f'P{line - 1}')
    data = np.array(values, dtype=float).reshape(-1, 3 + len(columns))
    if not np.all(np.isfinite(data)):
        raise ValueError(f'--points {path}: NaN or inf in the numbers')
    duplicate = sorted({n for n in names if names.count(n) > 1})
    if duplicate:
        raise ValueError(f'--points {path}: points named twice: {duplicate}')
    return Points(names, data[:, :3], data[:, 3:] if touched else None,
                  None if touched else data[:, 3:])


def calibrate_from_file(repo, cell, points_path: str | Path, *, method: str = 'rigid',
                        kinematics: str = 'active', T_base_tracker=None,
                        max_rms_error: float = MAX_RMS_ERROR, store: bool = True) -> dict:
    """Fit, gate, store and activate the user frame of a points file (module doc) in ``repo``
    (the cell's repository) through api.user_frame.calibrate, the service's path. The report
    (JSON-ready, mm): id, method, points, rms_mm, max_residual_mm, residuals_mm {name: mm},
    T_base_user, measured_through, stored, active. ValueError for a file that does not fit;
    core.errors.Refusal for a fit its gate refuses (nothing stored) or a store that cannot be
    written (STORAGE_FAILED)."""
    from cobot_calib_ros.api import user_frame as user_frame_api
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.core.user_frame.procedure import Gate
    model = model_for(cell)
    points = read_points(points_path, model.joint_names)
    p_base = None
    if points.measured is not None:
        T = np.eye(4) if T_base_tracker is None else np.asarray(T_base_tracker, dtype=float)
        p_base = points.measured @ T[:3, :3].T + T[:3, 3]
    elif T_base_tracker is not None:
        raise ValueError('--base-from-tracker applies to measured x,y,z, not to joints')
    request = user_frame_api.Request(
        method=method, names=tuple(points.names), p_user=points.p_user, p_base=p_base,
        joints=points.joints, kinematics=kinematics, frames=(cell.base_frame, cell.user_frame),
        gate=Gate(max_rms_error=max_rms_error), store=store)
    done = user_frame_api.calibrate(repo, cell, request, stamp_ns=time.time_ns(), model=model)
    if not done:
        if done.code == ErrorCode.INVALID_INPUT and done.message.startswith('kinematics '):
            raise ValueError(f'--{done.message}')
        refused = '' if done.code == ErrorCode.STORAGE_FAILED else 'REFUSED: '
        raise Refusal(Failure(ErrorCode(done.code), f'{refused}{done.message}'))
    fit = done.measured.fit
    return {'id': done.record['id'], 'method': fit.method, 'points': len(points.names),
            'rms_mm': fit.rms * 1e3, 'max_residual_mm': fit.max_residual * 1e3,
            'residuals_mm': dict(zip(points.names, (float(np.linalg.norm(r)) * 1e3
                                                    for r in fit.residuals))),
            'T_base_user': np.asarray(fit.T_base_user).tolist(),
            'measured_through': done.through, 'message': fit.message, 'stored': done.stored,
            'active': done.active}
