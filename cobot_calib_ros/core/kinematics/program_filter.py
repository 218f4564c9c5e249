"""Program filtering: pose targets for a controller that keeps its nominal kinematics.

The controller turns a pose target into joints with its nominal model. For the tool to end up
where the target says on the calibrated arm, it is given instead the pose its nominal model
reaches at the joints the calibrated model needs: q = IK_calibrated(T), T' = FK_nominal(q).
Its nominal inverse kinematics of T' then gives q again (same branch, seeded near; a redundant
arm's controller resolves its redundancy its own way, so there only T' is exact).

Targets are a CSV with the header ``name,x,y,z,qx,qy,qz,qw``: the tool pose in the targets'
frame (the base, or a user frame), position [m] and unit quaternion (x, y, z, w; the sign is
free). The filtered program has the same columns for the corrected pose, then the calibrated
model's joints [rad, m for prismatic] by joint name. A target the calibrated model cannot
reach (out of the workspace or the joint limits) is named with the solver's reason.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import io
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.frames import from_pose, invert, to_pose, transform_error
from cobot_calib_ros.core.kinematics.ik import solve_ik_with_restarts
from cobot_calib_ros.core.kinematics.model import Chain, fk

Array = NDArray[np.float64]

COLUMNS = ('name', 'x', 'y', 'z', 'qx', 'qy', 'qz', 'qw')
_UNIT = 1e-3          # |1 - |quaternion|| above this: not a rotation, refused


@dataclass(frozen=True)
class Target:
    name: str
    pose: Array          # (4, 4) tool pose in the targets' frame


@dataclass(frozen=True)
class Filtered:
    name: str
    pose: Array          # (4, 4) corrected tool pose in the targets' frame, for the controller
    q: Array             # (n,) the calibrated model's joints at the target
    correction_m: float  # |corrected - given| position [m]
    correction_rad: float


@dataclass(frozen=True)
class Unreachable:
    name: str
    reason: str

    def line(self) -> str:
        return f'target {self.name}: cannot be reached by the calibrated model ({self.reason})'


@dataclass(frozen=True)
class FilterResult:
    filtered: tuple[Filtered, ...]
    unreachable: tuple[Unreachable, ...]


def parse_targets(text: str, where: str = 'targets') -> list[Target]:
    """The targets of a CSV text (header ``name,x,y,z,qx,qy,qz,qw``); ValueError naming the
    line and column of a missing or non-finite number, a quaternion that is not unit, a
    repeated name or an empty file."""
    rows = csv.reader(io.StringIO(text))
    header = next(rows, None)
    if header is None or [h.strip() for h in header] != list(COLUMNS):
        raise ValueError(f'{where}: line 1: expected the header {",".join(COLUMNS)} (position '
                         '[m], unit quaternion x y z w)')
    targets, seen = [], set()
    for line, row in enumerate(rows, start=2):
        if not row or not ''.join(row).strip():
            continue
        if len(row) != len(COLUMNS):
            raise ValueError(f'{where}: line {line}: expected {len(COLUMNS)} columns, got '
                             f'{len(row)}')
        name = row[0].strip()
        if not name or name in seen:
            raise ValueError(f'{where}: line {line}: name {name!r} is empty or repeated; give '
                             'each target its own name')
        seen.add(name)
        values = []
        for column, cell in zip(COLUMNS[1:], row[1:]):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise ValueError(f'{where}: line {line}: {column}: expected a finite number, '
                                 f'got {cell.strip()!r}')
            values.append(value)
        quaternion = np.array(values[3:])
        norm = float(np.linalg.norm(quaternion))
        if abs(norm - 1.0) > _UNIT:
            raise ValueError(f'{where}: line {line}: the quaternion (qx qy qz qw) has norm '
                             f'{norm:.6g}; give a unit quaternion')
        targets.append(Target(name, from_pose(values[:3], quaternion / norm)))
    if not targets:
        raise ValueError(f'{where}: no targets after the header')
    return targets


def filter_targets(targets: list[Target], calibrated: Chain, nominal: Chain, home: ArrayLike,
                   T_base_frame: ArrayLike | None = None) -> FilterResult:
    """Each target solved with the calibrated chain (seeded from the previous target's joints,
    a program being a path, else ``home``), its corrected pose the nominal chain's FK there.
    ``T_base_frame``: the targets' frame in the base (a user frame; default the base); the
    corrected poses are in that frame too. Both chains end at the same tool."""
    T_base_frame = np.eye(4) if T_base_frame is None else np.asarray(T_base_frame, float)
    T_frame_base = invert(T_base_frame)
    home = np.asarray(home, dtype=float)
    filtered, unreachable, seed = [], [], home
    for target in targets:
        result = solve_ik_with_restarts(calibrated, T_base_frame @ target.pose, seed, home)
        if not result:
            unreachable.append(Unreachable(target.name, result.message))
            continue
        seed = result.q
        pose = T_frame_base @ fk(nominal, result.q)
        filtered.append(Filtered(target.name, pose, result.q.copy(),
                                 *transform_error(pose, target.pose)))
    return FilterResult(tuple(filtered), tuple(unreachable))


def filtered_csv(filtered: tuple[Filtered, ...], joint_names: tuple[str, ...]) -> str:
    """The filtered program: name, corrected pose (x y z [m], qx qy qz qw with qw >= 0), the
    calibrated joints; numbers as the shortest round-trip decimals."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(COLUMNS + tuple(joint_names))
    for f in filtered:
        position, quaternion = to_pose(f.pose)
        quaternion = -quaternion if quaternion[3] < 0 else quaternion
        writer.writerow([f.name] + [repr(float(v)) for v in (*position, *quaternion, *f.q)])
    return out.getvalue()
