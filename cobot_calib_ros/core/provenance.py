"""Provenance: a result is only as good as what it was measured through.

Every result names the results it was measured through (``measured_through``: kind -> id,
'nominal' for the cell's own value; a user frame touched live: the kinematics and the TCP; a
TCP or a hand-eye: the kinematics). When one of them is no longer the one in use, the result
is stale: :class:`Stale` says so in one line naming both ids and the size of the change at
the result (a user frame touched with TCP A and used with TCP B is off by about |B - A| at the
tool). The sizes are computed here from core.rig's typed records; store.rigs finds the stale
ones of an active set.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.frames import transform_error
from cobot_calib_ros.core.kinematics.model import fk

NAMES = {'kinematics': 'kinematics', 'tcp': 'TCP', 'hand_eye': 'hand-eye',
         'intrinsics': 'intrinsics', 'user_frame': 'user frame'}
REMEDIES = {'kinematics': 'identify again', 'tcp': 'calibrate the TCP again',
            'hand_eye': 'calibrate the hand-eye again',
            'intrinsics': 'calibrate the intrinsics again',
            'user_frame': 'touch the frame again'}


@dataclass(frozen=True)
class Stale:
    """Result ``id`` of ``kind`` was measured through ``through`` ``was``; ``now`` is in use.
    The size of the change at the result: ``change_mm`` (and ``change_mrad``) of a pose or a
    point, ``change_px`` of a lens; None: unknown (``was`` is not stored)."""

    kind: str
    id: str
    through: str
    was: str
    now: str
    change_mm: float | None = None
    change_mrad: float | None = None
    change_px: float | None = None
    where: str = ''         # where the change is measured, e.g. 'at the tool'

    def line(self) -> str:
        verb = 'touched' if self.kind == 'user_frame' and self.through == 'tcp' else (
            'identified' if self.kind == 'kinematics' else 'measured')
        name = NAMES[self.through]
        if self.change_mm is not None:
            size = f'{self.change_mm:.3f} mm' + (
                '' if self.change_mrad is None else f' / {self.change_mrad:.3f} mrad')
        elif self.change_px is not None:
            size = f'{self.change_px:.2f} px'
        else:
            size = ''
        away = f'is {size} away {self.where}'.rstrip() if size else \
            'differs by an amount not known here'
        return (f'{NAMES[self.kind]} {self.id} was {verb} with {name} {self.was}; the active '
                f'{name} {self.now} {away}: {REMEDIES[self.kind]}, or keep it')

    def to_dict(self) -> dict:
        return {**asdict(self), 'message': self.line()}


def tcp_change(was_T: ArrayLike, now_T: ArrayLike) -> float:
    """[m] between two T_flange_tool's tool points."""
    return float(np.linalg.norm(np.asarray(now_T, float)[:3, 3] - np.asarray(was_T, float)[:3, 3]))


def pose_change(was_T: ArrayLike, now_T: ArrayLike) -> tuple[float, float]:
    """([m], [rad]) between two poses of the same frame (a hand-eye, a user frame)."""
    return transform_error(np.asarray(now_T, float), np.asarray(was_T, float))


def kinematics_change(was, now, model, tool: ArrayLike, joints: ArrayLike) -> float:
    """[m] the largest move of the point ``tool`` (T_flange_tool) between the kinematic
    calibrations ``was`` and ``now`` (core.rig.Kinematics; None: nominal) over ``joints``
    (N, n) or (n,) (the result's own poses). ValueError: one is of another robot."""
    from cobot_calib_ros.core.rig import model_chain
    q = np.atleast_2d(np.asarray(joints, dtype=float))
    before = fk(model_chain(was, model, tool), q)[..., :3, 3]
    after = fk(model_chain(now, model, tool), q)[..., :3, 3]
    return float(np.max(np.linalg.norm(after - before, axis=-1)))


def lens_change(was_K: ArrayLike, now_K: ArrayLike) -> float:
    """[px] the largest change of the focal lengths and principal point."""
    was, now = np.asarray(was_K, float), np.asarray(now_K, float)
    return float(np.max(np.abs(now[[0, 1, 0, 1], [0, 1, 2, 2]] - was[[0, 1, 0, 1],
                                                                   [0, 1, 2, 2]])))


def missing_prerequisites(what: str, through: dict[str, str]) -> str:
    """'' when every result ``what`` is measured through (kind -> id) is a calibrated one,
    else the note naming the missing ones (a calibration may start before them; it is then
    consistent with the cell's nominal values, and stale once they are calibrated)."""
    missing = [NAMES[kind] for kind, used in through.items() if used == 'nominal']
    if not missing:
        return ''
    names = ' and '.join(filter(None, (', '.join(missing[:-1]), missing[-1])))
    return (f'{what} measured through the nominal {names} (none calibrated is active): '
            f'calibrate {"them" if len(missing) > 1 else "it"} first for a result consistent '
            'with the calibrated cell')
