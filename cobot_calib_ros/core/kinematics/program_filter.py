"""Program filtering: pose targets for a controller that keeps its nominal kinematics.

The controller turns a pose target into joints with its nominal model. For the tool to end up
where the target says on the calibrated arm, it is given instead the pose its nominal model
reaches at the joints the calibrated model needs: q = IK_calibrated(T), T' = FK_nominal(q).
Its nominal inverse kinematics of T' then gives q again (same branch, seeded near; a redundant
arm's controller resolves its redundancy its own way, so there only T' is exact).

Targets are a CSV: ``name`` and the tool pose in the targets' frame (the base, or a user
frame), by default ``x,y,z,qx,qy,qz,qw`` (position [m], unit quaternion x y z w, the sign free),
or in a controller's own values and units (``fmt`` one of core.vendor_frames.FORMATS, e.g. kuka
``X,Y,Z,A,B,C`` [mm, deg], as a pendant shows a position). The filtered program has the same
columns for the corrected pose, then the calibrated model's joints [rad, m for prismatic] by
joint name. A target the calibrated model cannot reach is named with why: beyond the arm's
reach (its distance to the reachable sphere, the link lengths and the tool added up around the
first joint; a position a thousand times too far looks like millimetres and is said so), else
the solver's reason (the joint limits, an orientation it cannot take).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import io
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import from_pose, invert, to_pose, transform_error
from cobot_calib_ros.core.kinematics.model import Chain, fk
from cobot_calib_ros.core.rig import solve_target
from cobot_calib_ros.core.vendor_frames import FORMATS, from_values, to_values

Array = NDArray[np.float64]

COLUMNS = ('name', 'x', 'y', 'z', 'qx', 'qy', 'qz', 'qw')   # the default format, 'csv'
FORMAT_NAMES = ('csv',) + tuple(FORMATS)
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


def columns(fmt: str = 'csv') -> tuple[str, ...]:
    """The header of a targets file in ``fmt`` ('csv' or a vendor format); ValueError if
    unknown."""
    if fmt == 'csv':
        return COLUMNS
    if fmt not in FORMATS:
        raise ValueError(f'unknown targets format {fmt!r}; use one of {", ".join(FORMAT_NAMES)}')
    return ('name',) + FORMATS[fmt].labels


def _units(fmt: str) -> str:
    if fmt == 'csv':
        return 'position [m], unit quaternion x y z w'
    return ', '.join(f'{label} [{unit}]' if unit else label
                     for label, unit in zip(FORMATS[fmt].labels, FORMATS[fmt].units))


def parse_targets(text: str, where: str = 'targets', fmt: str = 'csv') -> list[Target]:
    """The targets of a CSV text (header :func:`columns` of ``fmt``); ValueError naming the
    line and column of a missing or non-finite number, a rotation that is not one, a repeated
    name or an empty file."""
    header_names = columns(fmt)
    rows = csv.reader(io.StringIO(text))
    header = next(rows, None)
    if header is None or [h.strip() for h in header] != list(header_names):
        raise ValueError(f'{where}: line 1: expected the header {",".join(header_names)} '
                         f'({_units(fmt)})')
    targets, seen = [], set()
    for line, row in enumerate(rows, start=2):
        if not row or not ''.join(row).strip():
            continue
        if len(row) != len(header_names):
            raise ValueError(f'{where}: line {line}: expected {len(header_names)} columns, got '
                             f'{len(row)}')
        name = row[0].strip()
        if not name or name in seen:
            raise ValueError(f'{where}: line {line}: name {name!r} is empty or repeated; give '
                             'each target its own name')
        seen.add(name)
        values = []
        for column, cell in zip(header_names[1:], row[1:]):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise ValueError(f'{where}: line {line}: {column}: expected a finite number, '
                                 f'got {cell.strip()!r}')
            values.append(value)
        try:
            targets.append(Target(name, _pose(values, fmt)))
        except ValueError as exc:
            raise ValueError(f'{where}: line {line}: {exc}') from None
    if not targets:
        raise ValueError(f'{where}: no targets after the header')
    return targets


def _pose(values: list[float], fmt: str) -> Array:
    if fmt != 'csv':
        return from_values(values, fmt)
    quaternion = np.array(values[3:])
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > _UNIT:
        raise ValueError(f'the quaternion (qx qy qz qw) has norm {norm:.6g}; give a unit '
                         'quaternion')
    return from_pose(values[:3], quaternion / norm)


def _values(pose: Array, fmt: str) -> tuple[float, ...]:
    if fmt != 'csv':
        return to_values(pose, fmt)
    position, quaternion = to_pose(pose)
    return tuple(position) + tuple(-quaternion if quaternion[3] < 0 else quaternion)


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
        result = solve_target(calibrated, target.pose, seed, home, T_base_frame)
        if not result:
            far = out_of_reach(calibrated, (T_base_frame @ target.pose)[:3, 3])
            unreachable.append(Unreachable(target.name, (result if far is None else far).message))
            continue
        seed = result.q
        pose = T_frame_base @ fk(nominal, result.q)
        filtered.append(Filtered(target.name, pose, result.q.copy(),
                                 *transform_error(pose, target.pose)))
    return FilterResult(tuple(filtered), tuple(unreachable))


def reach(chain: Chain) -> float:
    """[m] the farthest the tool centre can be from the first joint's origin: the chain's
    link lengths and the tool's added up."""
    links = np.linalg.norm(np.asarray(chain.placements)[1:, :3, 3], axis=1).sum()
    return float(links + np.linalg.norm((chain.flange @ chain.tool)[:3, 3]))


def out_of_reach(chain: Chain, p_base: ArrayLike) -> Failure | None:
    """None when the position ``p_base`` [m] is within :func:`reach` of the first joint, else
    a MOTION_FAILED Failure saying how far beyond it is, and a hint when it looks like
    millimetres."""
    p = np.asarray(p_base, dtype=float)
    distance = float(np.linalg.norm(p - np.asarray(chain.placements)[0, :3, 3]))
    limit = reach(chain)
    if distance <= limit:
        return None
    hint = ('; it looks like millimetres: give the position in metres (or a --format in mm)'
            if distance > 20.0 * limit and distance * 1e-3 <= limit else '')
    return Failure(ErrorCode.MOTION_FAILED,
                   f'{distance:.4g} m from the first joint, {distance - limit:.4g} m beyond '
                   f'the arm\'s reach of {limit:.4g} m with this tool{hint}')


def filtered_csv(filtered: tuple[Filtered, ...], joint_names: tuple[str, ...],
                 fmt: str = 'csv') -> str:
    """The filtered program: name, corrected pose in ``fmt`` (csv: qw >= 0), the calibrated
    joints; numbers as the shortest round-trip decimals."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator='\n')
    writer.writerow(columns(fmt) + tuple(joint_names))
    for f in filtered:
        writer.writerow([f.name] + [repr(float(v)) for v in (*_values(f.pose, fmt), *f.q)])
    return out.getvalue()
