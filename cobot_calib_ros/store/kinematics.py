"""Kinematic calibrations: records like the user-frame ones, plus YAML and a calibrated URDF.

Under ``<root>/kinematics``: ``<id>.json`` (the record, what the suite reads), ``<id>.yaml``
(the same for people: the identified table as the paper's Table 6, validation figures) and
``<id>.urdf`` (the calibrated model for MoveIt, RViz, robot_state_publisher: the cell's own
URDF with the identified joint origins when the cell names it, else a minimal chain) and, for a
UR arm, ``<id>.ur_kinematics.yaml`` (``kinematics_params`` of the UR ROS 2 description).
Activation is per cell (store.cells) and robot (the record's ``robot``): a plant keeps many robots'
results in one data dir, and ``kinematics: latest`` in user_frame_solver and
repeatability_trial is the active calibration *of the cell's robot* (:class:`CalibrationStore`
rules within that robot: chosen, else the newest non-retired), nominal when it has none.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cobot_calib_ros.core.ids import utc_text
from cobot_calib_ros.core.kinematics.model import KinematicModel
from cobot_calib_ros.core.kinematics.robots import UrdfRobot
from cobot_calib_ros.core.kinematics.ur_description import (is_ur, ur_kinematics,
                                                            ur_kinematics_yaml)
from cobot_calib_ros.core.kinematics.urdf import calibrated_urdf, rewrite_urdf
from cobot_calib_ros.store.calibrations import Activation, CalibrationStore
from cobot_calib_ros.store.files import atomic_write_text, dump_yaml, ensure_dir
from cobot_calib_ros.store.records import KinematicRecord

NOMINAL = 'nominal'
SUFFIXES = {'urdf': '.urdf', 'ur_kinematics': '.ur_kinematics.yaml'}   # beside <id>.json
LATEST = 'latest'


@dataclass(frozen=True)
class SavedKinematics:
    """What :meth:`KinematicStore.save_outcome` wrote: the record, the paths of its JSON (or
    where a database keeps it), YAML and URDF files, and its activation (None if not asked
    for)."""

    record: KinematicRecord
    paths: dict[str, Path]
    activation: Activation | None


class KinematicHistory:
    """What a kinematic calibration history adds to a calibration history (a mixin of
    :class:`KinematicStore` and store.database's): the YAML and URDF files beside each record
    (in ``directory``), and the choice of a model by name."""

    def save_outcome(self, outcome, activate: bool = True, wall_ns: int | None = None,
                     extra: dict[str, Any] | None = None,
                     description: UrdfRobot | None = None) -> SavedKinematics:
        """Write the record of a core CalibrationJob outcome (JSON), its YAML and URDF (and a
        UR arm's kinematics YAML); make it its robot's active one (if ``activate`` and it
        passes its gate). ``extra``: more top-level keys of the record (e.g. the planning of a
        planned collection). ``description``: the cell's robot URDF (with its text), which
        the URDF is written back into (:func:`calibrated_descriptions`)."""
        typed = KinematicRecord.from_outcome(outcome, wall_ns)
        typed.extra.update(extra or {})
        # a sphere coupling or a tracker's reflector is fitted with the arm: measured through
        # no other result (the contract's provenance)
        typed.extra.setdefault('measured_through', {})
        typed.extra.setdefault('unseen', outcome_unseen(outcome))
        return self.save_record(typed, outcome.model, activate, description)

    def save_record(self, typed: KinematicRecord, model: KinematicModel, activate: bool = True,
                    description: UrdfRobot | None = None) -> SavedKinematics:
        """Write a kinematic record (JSON), its YAML and URDF (and a UR arm's kinematics
        YAML), whatever made it (a CalibrationJob outcome, a measurement file's
        identification); make it its robot's active one if ``activate`` (and it passes its
        gate). ``description``: the robot's URDF (with its text), written back into. The
        files come first: a reader that sees the record finds them (a record refused, invalid
        or another cell's, writes nothing)."""
        texts = calibrated_descriptions(typed, model, description)  # before any write
        record = self._checked(typed)
        paths = {'yaml': self.directory / f'{typed.id}.yaml'}
        ensure_dir(self.directory)
        atomic_write_text(paths['yaml'], dump_yaml(_readable(record), sort_keys=False,
                                                   width=100))
        for kind, text in texts.items():
            paths[kind] = self.directory / f'{typed.id}{SUFFIXES[kind]}'
            atomic_write_text(paths[kind], text)
        stored = self._put(record)       # a path, or where in a database
        activation = self.activate(typed.id) if activate else None
        return SavedKinematics(typed, {'json': stored, **paths}, activation)

    def resolve(self, choice: str, robot: str) -> dict[str, Any] | None:
        """The record ``choice`` names for ``robot`` (a model name): 'latest' (that robot's
        active one, None if it has none), 'nominal' (None) or an id (KeyError if not stored;
        :func:`core.rig.model_chain` refuses one of another robot)."""
        if choice in ('', NOMINAL):
            return None
        if choice == LATEST:
            return self.active(robot)
        record = self.get(choice)
        if record is None:
            raise KeyError(f'no kinematic calibration {choice!r} in {self.directory}')
        return record


class KinematicStore(KinematicHistory, CalibrationStore):
    def __init__(self, root: Path, cell=None) -> None:
        super().__init__(root, 'kinematics', scope_key='robot', cell=cell)


def outcome_unseen(outcome) -> list[dict]:
    """What a CalibrationJob's measurement (a sphere coupling or a tracker's reflector: one
    point on the tool) cannot see (core writeback.unseen)."""
    from cobot_calib_ros.core.kinematics.identification.writeback import unseen
    kind = 'spheres' if outcome.inputs.objective == 'relative' else 'points'
    return unseen(outcome.model, kind, 1, [{'name': d.name, 'reason': d.reason}
                                           for d in outcome.identifiability.dropped])


def calibrated_descriptions(record: KinematicRecord, model: KinematicModel,
                            description: UrdfRobot | None) -> dict[str, str]:
    """The texts a kinematic calibration is written back as: 'urdf', the robot's own URDF
    (``description``, with its text) with the identified joint origins and a comment naming
    the calibration, else a minimal URDF of the chain (the tool at the identified tool
    position); and 'ur_kinematics', the UR description's kinematics YAML, for a UR arm with
    its URDF. ValueError when the URDF's chain is not the model's."""
    params = np.array(record.result.params, dtype=float)
    note = (f'calibrated by cobot_calib_ros: kinematic calibration {record.id} of robot '
            f'{record.robot}, {utc_text(record.stamp_ns)}, {record.method} from '
            f'{record.inputs.source}; only the origins of {", ".join(model.joint_names)} '
            'differ from the nominal description')
    unseen = record.extra.get('unseen') or ()
    if unseen:
        note += '\n' + unseen_note(unseen)
    if description is None or not description.urdf:
        tool = record.result.p_flange_tool
        return {'urdf': calibrated_urdf(model, params, None if tool is None else np.array(tool),
                                        robot_name=f'{model.name}_calibrated')}
    urdf = rewrite_urdf(description.urdf, model, params, base_link=description.base_link,
                        tip_link=description.tip_link, note=note)
    texts = {'urdf': urdf}
    if is_ur(model.joint_names):
        texts['ur_kinematics'] = ur_kinematics_yaml(ur_kinematics(urdf, model.joint_names),
                                                    f'cobot_calib_{record.id}', note)
    return texts


def unseen_note(unseen) -> str:
    """One line naming the parameters a record's measurement could not see (kept at nominal),
    grouped by why, and what they affect: the written URDF's comment, the report, filter's and
    move's notes."""
    by_reason: dict[str, list[str]] = {}
    for u in unseen:
        by_reason.setdefault(u['reason'], []).append(u['name'])
    return 'not seen by the measurement, kept nominal: ' + '; '.join(
        f'{", ".join(names)} ({reason})' for reason, names in by_reason.items())


def unseen_tool_note(record: dict[str, Any] | None) -> str:
    """'' or the line naming what a kinematic calibration ``record`` could not see that
    every tool carries: filter and move say it when they use the record."""
    unseen = [u for u in (record or {}).get('unseen', ()) if u.get('affects') == 'tool']
    return f'{record["id"]}: {unseen_note(unseen)}' if unseen else ''


def _readable(record: dict[str, Any]) -> dict[str, Any]:
    """The record for people: no full parameter vector, the table as lines."""
    result = dict(record['result'])
    table = result.pop('table6', '')
    result.pop('params', None)
    result.pop('parameter_names', None)
    free = result.pop('free')
    result['identified'] = {name: {'value': value, 'std': std} for name, value, std in zip(
        free, result.pop('values'), result.pop('std') or [None] * len(free))}
    return {**{k: v for k, v in record.items() if k != 'result'}, 'result': result,
            'table6': table.splitlines()}
