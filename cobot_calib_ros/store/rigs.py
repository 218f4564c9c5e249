"""A cell's active results (core.rig.ActiveSet) and its rig (core.rig.Rig): what every node,
check and verb asks for "which chain, with which tool", "which lens", "which user frame".

The typed records of core.rig are built here from the stored records (their dicts); core reads
no storage keys. :data:`KINDS` declares each result kind once: where the repository keeps it
and how its typed record is built; :func:`active_set` gathers them and finds the stale ones
(core.provenance).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import json
from pathlib import Path
from typing import Any

import numpy as np

from cobot_calib_ros.core import provenance, rig
from cobot_calib_ros.core.errors import Refusal
from cobot_calib_ros.core.kinematics.robots import model_for
from cobot_calib_ros.core.rig import ActiveSet, NOMINAL, Rig
from cobot_calib_ros.store.kinematics import unseen_tool_note
from cobot_calib_ros.store.renamed import with_current_names

ACTIVE = ('active', 'latest')
Stored = Mapping[str, Any]


def measured_through(record: Stored | None) -> dict[str, str]:
    """The record's ``measured_through`` (kind -> id; {} for records written before it)."""
    value = None if record is None else record.get('measured_through')
    return {str(k): str(v) for k, v in value.items()} if isinstance(value, Mapping) else {}


def _matrix(value) -> np.ndarray | None:
    try:
        T = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None


def kinematics_of(record: Stored | None) -> rig.Kinematics | None:
    """The typed kinematic calibration of a stored record (None: None)."""
    if record is None:
        return None
    result = record['result']
    tool = result.get('p_flange_tool')
    return rig.Kinematics(record['id'], str(record.get('robot', '')),
                          tuple(result['parameter_names']),
                          np.array(result['params'], dtype=float),
                          None if tool is None else np.array(tool, dtype=float),
                          measured_through(record), unseen_tool_note(record))


def tcp_of(record: Stored | None) -> rig.Tcp | None:
    """The typed TCP of a stored record; None when there is none or it does not read as a
    transform (the cell's T_flange_tool is used then)."""
    T = None if record is None else _matrix(record['result'].get('T_flange_tool'))
    if T is None:
        return None
    return rig.Tcp(record['id'], str(record.get('tool', '')), T,
                   record['result'].get('orientation_method', 'none') != 'none',
                   measured_through(record))


def hand_eye_of(record: Stored | None) -> rig.HandEye | None:
    """The typed hand-eye of a stored record; None when there is none or it does not read as
    a transform (the cell's nominal hand-eye is used then)."""
    X = None if record is None else _matrix(record['result'].get('T_flange_optical'))
    return None if X is None else rig.HandEye(record['id'], X, measured_through(record))


def intrinsics_of(record: Stored | None) -> rig.Intrinsics | None:
    """The typed intrinsics of a stored record; None when there is none or it does not read
    (the nominal CameraInfo holds then)."""
    if record is None:
        return None
    from cobot_calib_ros.store.records import IntrinsicsRecord
    try:
        typed = IntrinsicsRecord.from_dict(record)
        return rig.Intrinsics(typed.id, typed.camera, typed.camera_model(),
                              measured_through(record))
    except (KeyError, TypeError, ValueError):
        return None


def user_frame_of(record: Stored | None) -> rig.UserFrame | None:
    """The typed user frame of a stored record; None when it has no readable frame."""
    T = None if record is None else _matrix(record.get('result', {}).get('T_base_user'))
    return None if T is None else rig.UserFrame(record['id'], T, measured_through(record))


@dataclass(frozen=True)
class Kind:
    """A result kind: the repository's history of it, its typed record, and how its active one
    is looked up (``scope``: of the cell; None: the history's one active record)."""

    history: str
    typed: Callable[[Stored | None], Any]
    scope: Callable[[Any], str] | None = None


KINDS: dict[str, Kind] = {
    'kinematics': Kind('kinematics', kinematics_of, lambda cell: model_for(cell).name),
    'tcp': Kind('tcp', tcp_of, lambda cell: cell.tool_frame),
    'hand_eye': Kind('hand_eye', hand_eye_of),
    'intrinsics': Kind('intrinsics', intrinsics_of,
                       lambda cell: cell.camera.frame_id if cell.camera else ''),
    'user_frame': Kind('user_frames', user_frame_of),
}


def history_of(repository, kind: str):
    """The repository's history (store.calibrations) of ``kind`` (one of :data:`KINDS`)."""
    return getattr(repository, KINDS[kind].history)


def kinematic_record(repository, model, choice: str = 'active') -> dict[str, Any] | None:
    """The stored kinematic calibration ``choice`` names: 'active' / 'latest' (the robot's
    active one, None when it has none), 'nominal' (None), an id, or an <id>.json file.
    ValueError saying what to do."""
    if choice.endswith('.json'):
        try:
            return with_current_names(json.loads(Path(choice).expanduser().read_text(
                encoding='utf-8')))
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise ValueError(f'--kinematics {choice}: cannot read a calibration record '
                             f'({exc})') from None
    try:
        return repository.kinematics.resolve('latest' if choice in ACTIVE else choice,
                                             model.name)
    except KeyError as exc:
        raise ValueError(f'kinematics: {exc.args[0]}') from None


def active_result(repository, cell, kind: str):
    """The typed active result of ``kind`` (one of :data:`KINDS`) of ``cell``, None when
    there is none or it does not read (the cell's nominal value holds): one kind of
    :func:`active_set`, for a consumer that follows that kind alone."""
    spec = KINDS[kind]
    try:
        history = history_of(repository, kind)
        record = history.active(spec.scope(cell)) if spec.scope else history.active()
    except (OSError, ValueError):
        return None
    return spec.typed(record)


def active_set(repository, cell, kinematics: str = 'active', user_frame: str = '',
               model=None) -> ActiveSet:
    """``cell``'s active results as typed records: the kinematic calibration ``kinematics``
    names (:func:`kinematic_record`), the active TCP of the cell's tool, hand-eye, intrinsics
    of its wrist camera and user frame (``user_frame``: that one by id instead), and which of
    them are stale (:func:`stale_results`). ValueError: no such calibration, or a user frame
    id not stored (both say what to do)."""
    model = model_for(cell) if model is None else model
    frame = active_result(repository, cell, 'user_frame')
    if user_frame:
        frame = user_frame_of(repository.user_frames.get(user_frame))
        if frame is None:
            raise ValueError(f'no user frame {user_frame!r} in the results of cell '
                             f'{repository.cell}; list them with `cobot-calib history`')
    active = ActiveSet(kinematics_of(kinematic_record(repository, model, kinematics)),
                       active_result(repository, cell, 'hand_eye'),
                       active_result(repository, cell, 'tcp'), frame,
                       active_result(repository, cell, 'intrinsics'))
    return ActiveSet(active.kinematics, active.hand_eye, active.tcp, active.user_frame,
                     active.intrinsics, stale_results(repository, cell, active, model))


def rig_of(repository, cell, kinematics: str = 'active', model=None) -> Rig:
    """``cell``'s rig with its active set (:func:`active_set`; ValueError)."""
    model = model_for(cell) if model is None else model
    return Rig(cell, active_set(repository, cell, kinematics, model=model), model)


def stale_results(repository, cell, active: ActiveSet, model=None
                  ) -> tuple[provenance.Stale, ...]:
    """The results of ``active`` measured through a result that is not the one ``active``
    holds, with the size of the change at the result (core.provenance)."""
    model = model_for(cell) if model is None else model
    return tuple(stale for kind in rig.KINDS if getattr(active, kind) is not None
                 for stale in staleness(repository, cell, active, kind, getattr(active, kind),
                                        model))


def staleness(repository, cell, active: ActiveSet, kind: str, result, model=None
              ) -> tuple[provenance.Stale, ...]:
    """How ``result`` (a typed record of ``kind``, active or not) is stale against ``active``:
    one core.provenance.Stale per result it was measured through that ``active`` does not
    hold."""
    model = model_for(cell) if model is None else model
    return tuple(_stale(repository, cell, model, active, kind, result, through, was)
                 for through, was in result.measured_through.items()
                 if through in rig.KINDS and was != active.label(through))


def _stale(repository, cell, model, active: ActiveSet, kind: str, result, through: str,
           was: str) -> provenance.Stale:
    now = getattr(active, through)
    before = None
    if was != NOMINAL:
        try:
            before = KINDS[through].typed(history_of(repository, through).get(was))
        except (OSError, ValueError, KeyError, Refusal):
            before = None
        if before is None:
            return provenance.Stale(kind, result.id, through, was, active.label(through))
    sizes: dict[str, Any] = {}
    if through == 'tcp':
        sizes = {'change_mm': provenance.tcp_change(
            rig.T_flange_tool(cell, 'tcp', tcp=before), rig.T_flange_tool(cell, 'tcp', tcp=now))
            * 1e3, 'where': 'at the tool'}
    elif through == 'kinematics':
        joints = _joints(repository, kind, result.id)
        tool = rig.T_flange_tool(cell, 'tcp', tcp=active.tcp) if kind == 'user_frame' else \
            np.eye(4)
        try:
            change = provenance.kinematics_change(before, now, model, tool,
                                                  cell.home if joints is None else joints)
        except ValueError:      # of another robot
            return provenance.Stale(kind, result.id, through, was, active.label(through))
        where = 'at the home pose' if joints is None else f'over its {len(joints)} poses'
        sizes = {'change_mm': change * 1e3,
                 'where': f'at the {"tool" if kind == "user_frame" else "flange"} {where}'}
    elif through in ('hand_eye', 'user_frame'):
        key = 'T_flange_optical' if through == 'hand_eye' else 'T_base_user'
        nominal = cell.camera.T_flange_optical if through == 'hand_eye' and cell.camera \
            else None
        was_T = nominal if before is None else getattr(before, key)
        now_T = nominal if now is None else getattr(now, key)
        if was_T is not None and now_T is not None:
            m, r = provenance.pose_change(was_T, now_T)
            sizes = {'change_mm': m * 1e3, 'change_mrad': r * 1e3,
                     'where': 'at the camera' if through == 'hand_eye' else 'at its origin'}
    elif through == 'intrinsics' and cell.camera is not None:
        nominal = cell.camera.camera_model().K
        sizes = {'change_px': provenance.lens_change(
            nominal if before is None else before.model.K,
            nominal if now is None else now.model.K),
            'where': 'in the focal lengths and principal point'}
    return provenance.Stale(kind, result.id, through, was, active.label(through), **sizes)


def _joints(repository, kind: str, result_id: str) -> np.ndarray | None:
    """(N, n) the joints a result was measured at, None when its record has none."""
    try:
        record = history_of(repository, kind).get(result_id)
        q = np.array(record['inputs']['joints'], dtype=float)
    except (AttributeError, KeyError, OSError, TypeError, ValueError, Refusal):
        return None
    return q if q.ndim == 2 and q.size else None
