"""The kinematic calibration kind's api (issue 39.2): one call to collect, one to identify.

:func:`collect` opens a collection in the store (a stored one of this cell to resume, or a new
one set up by core.kinematics.kinematic_collection) and runs the core procedure over a robot
port, every pose stored as it is measured, the planning state and status stored at the end.
:func:`identify` runs the one CalibrationJob on a source, gates it and, when it passes, stores
it, writes the URDF (and a UR arm's kinematics YAML) back and makes it active.
kinematic_identifier's goals and ``cobot-calib identify --source`` both end here;
:func:`goal_source` finds what a goal names (a file, a stored collection, validation sets).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.core.kinematics.collection import PoseRecord
from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds
from cobot_calib_ros.core.kinematics.identification.measurement_fit import LOSSES, SOLVERS
from cobot_calib_ros.core.kinematics.kinematic_calibration import (CalibrationJob, JobCancelled,
                                                                   OBJECTIVES, Outcome)
from cobot_calib_ros.core.kinematics.kinematic_collection import (
    collect_kinematics, Collected, CollectionRequest, new_collection, OnProgress, Resume,
    Unfinished)
from cobot_calib_ros.core.robot_port import Cancelled, never, RobotPort
from cobot_calib_ros.loaders import sources
from cobot_calib_ros.store.files import check_id


# -- collection ------------------------------------------------------------------------------
def collect(collections, cell, model, results_cell, request: CollectionRequest,
            robot: RobotPort, *, collection_id: str = '', hold: float,
            cancelled: Cancelled = never, progress: OnProgress | None = None,
            say: Callable[[str], None] = lambda _: None) -> Collected | Failure:
    """Collect on ``robot`` into ``collections`` (store.collections.CollectionStore) of
    ``results_cell``: the stored unfinished collection ``collection_id`` resumed, else a new
    one (that id, or a new one). The Collected, or a Failure: INVALID_INPUT before anything is
    stored or moved, STORAGE_FAILED, or an Unfinished one (resumable) that carries it."""
    try:
        opened = _open(collections, cell, model, results_cell, request, collection_id, say)
    except OSError as e:
        return Failure(ErrorCode.STORAGE_FAILED, f'could not store the collection: {e}; '
                       'check data_dir')
    if not opened:
        return opened
    meta, resume = opened
    got = collect_kinematics(model, meta, resume, robot, _log(collections, meta['id']),
                             hold=hold, cancelled=cancelled, progress=progress)
    collected = got.collected if isinstance(got, Unfinished) else got
    try:
        if collected.planning is not None:
            collections.update(meta['id'], planning=collected.planning)
        collections.set_status(meta['id'], 'done' if got else 'aborted')
    except (OSError, ValueError) as e:
        return Unfinished(ErrorCode.STORAGE_FAILED, f'{meta["id"]}: could not store its '
                          f'status and planning: {e}; check data_dir', collected)
    if not got:
        return got
    return replace(got, message=f'{meta["id"]}: {got.recorded} poses recorded, {got.skipped} '
                   f'skipped ({got.message}); robot time {got.time.total:.1f} s '
                   f'({got.time.at_hold():.1f} s at a 1 s hold)')


def _open(collections, cell, model, results_cell, request, collection_id, say
          ) -> tuple[dict, Resume] | Failure:
    """The collection's metadata and what it has: a stored one of this cell to resume, else
    a new one created in the store."""
    if collection_id:
        try:
            stored = collections.load(check_id(collection_id))
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, str(e))
        if stored is not None:
            meta = stored.meta
            foreign = results_cell.problem(meta.get('cell', ''), meta.get('robot', ''))
            if foreign is not None:
                return Failure(foreign.code, (
                    f'collection {collection_id} is not this cell\'s: {foreign.message}; '
                    'resume it on its own cell\'s suite, or give a new id (or none)'))
            if meta['status'] == 'done':
                return Failure(ErrorCode.INVALID_INPUT, f'collection {collection_id} is '
                               'complete; give a new id (or none) to collect again')
            collections.set_status(collection_id, 'running')
            return meta, Resume(stored.index.tolist(), stored.q, dict(stored.skipped),
                                stored.next_index)
    new = new_collection(cell, model, request, say)
    if not new:
        return new
    meta = collections.create(collection_id or record_id(new.prefix), source=new.source,
                              robot=cell.robot, joint_names=model.joint_names,
                              targets=new.targets, plan=new.plan,
                              extra={**new.extra, 'cell': results_cell.name})
    return meta, Resume(q=np.zeros((0, len(model.joint_names))))


def _log(collections, collection_id: str) -> Callable[[PoseRecord], None]:
    def log(record: PoseRecord) -> None:
        collections.append(collection_id, record.index, record.target, record.q,
                           sample_count=record.sample_count, std_max=record.std_max,
                           p=record.p, note=record.note)
    return log


# -- identification --------------------------------------------------------------------------
@dataclass(frozen=True)
class JobSource:
    """What an identification runs on: a loaders.sources.Source (a bag or a collection) and
    the laser-tracker sets it is validated on (region -> PositionObservations)."""

    source: Any
    validation: dict = field(default_factory=dict)

    @property
    def partial(self) -> str:
        return self.source.provenance.get('partial', '')


@dataclass(frozen=True)
class Settings:
    """How to identify: solver, loss, objective (None: from the data), an even subset of
    ``max_configs`` rows (0: all), the deviation bounds [m, rad]."""

    solver: str = 'lm'
    loss: str = 'soft_l1'
    objective: str | None = None
    max_configs: int = 0
    bounds: DeviationBounds = field(default_factory=DeviationBounds)

    def problem(self) -> Failure | None:
        for name, value, known in (('solver', self.solver, SOLVERS), ('loss', self.loss, LOSSES),
                                   ('objective', self.objective or OBJECTIVES[0], OBJECTIVES)):
            if value not in known:
                return Failure(ErrorCode.INVALID_INPUT,
                               f'unknown {name} {value!r}; use one of {", ".join(known)}')
        return None


@dataclass(frozen=True)
class Identified:
    """A passing identification: the outcome, where it was stored (store.kinematics.
    SavedKinematics; None: a dry run), and a line to report."""

    outcome: Outcome
    saved: Any
    message: str


@dataclass(frozen=True)
class GateRefused(Failure):
    """IMPLAUSIBLE_FIT: the identification ran and its gate refused it; nothing stored."""

    outcome: Outcome | None = None


def identify(job: JobSource, settings: Settings, kinematics=None, *,
             cancelled: Cancelled = never,
             progress: Callable[[int, float, float], None] | None = None
             ) -> Identified | Failure:
    """Identify ``job`` (core CalibrationJob), gate it and, if it passes and ``kinematics``
    (a store.kinematics.KinematicStore; None: a dry run) is given, store it with the cell's
    URDF written back and make it active. ``progress(iteration, cost, rms_m)`` each iteration;
    ``cancelled()`` between them. Failures: INVALID_INPUT, the gates' refusal of the data
    (its cause), SOLVER_FAILED, CANCELED, GateRefused, STORAGE_FAILED."""
    problem = settings.problem()
    if problem is not None:
        return problem
    source, partial = job.source, job.partial
    try:
        calibration = CalibrationJob(
            source.cell, source.model, source.observations,
            source=source.provenance.get('collection', str(source.path)),
            solver=settings.solver, loss=settings.loss, objective=settings.objective,
            max_configs=settings.max_configs, validation=job.validation,
            bounds=settings.bounds)
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, _joined(str(e), partial))

    def callback(iteration: int, cost: float, rms: float) -> bool:
        if progress is not None:
            progress(iteration, cost, rms)
        return not cancelled()
    try:
        outcome = calibration.run(callback)
    except JobCancelled:
        return Failure(ErrorCode.CANCELED, 'canceled; nothing stored')
    except Refusal as e:
        return Failure(e.failure.code, _joined(str(e), 'nothing stored', partial))
    except (ValueError, np.linalg.LinAlgError) as e:
        return Failure(ErrorCode.SOLVER_FAILED, _joined(str(e), partial))
    if not outcome.verdict.passed:
        return GateRefused(ErrorCode.IMPLAUSIBLE_FIT,
                           _joined(outcome.summary(), 'nothing stored', partial), outcome)
    saved = None
    if kinematics is not None:
        planning = source.provenance.get('planning')
        try:
            saved = kinematics.save_outcome(outcome,
                                            extra={'planning': planning} if planning else None,
                                            description=source.cell.urdf_robot)
        except (OSError, ValueError) as e:     # ValueError: the cell's URDF is not the chain
            return Failure(ErrorCode.STORAGE_FAILED,
                           f'could not store the kinematic calibration: {e}')
    return Identified(outcome, saved, _joined(outcome.summary(), partial))


def _joined(*parts: str) -> str:
    return '; '.join(filter(None, parts))


def goal_source(collections, cell, model, results_cell, *, file: str = '',
                collection_id: str = '', objective: str | None = None,
                validation: dict[str, str] | None = None) -> JobSource | Failure:
    """What a kinematic_identifier goal names: a ``file`` (a bag or a collection folder) or
    the stored collection ``collection_id`` of this cell (else the newest finished one of the
    objective's source), and the laser-tracker sets named in ``validation`` (region -> id;
    '' the newest finished one of the region, if any)."""
    try:
        if file:
            source = _file_source(file, cell)
        else:
            kind = 'laser_tracker' if objective == 'absolute' else 'spheres'
            source = sources.of_collection(_collection(
                collections, cell, results_cell, collection_id, kind), cell, model)
        sets = validation_sets(collections, cell, results_cell, validation or {})
    except Refusal as e:
        return e.failure
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    return JobSource(source, sets)


def validation_sets(collections, cell, results_cell, named: dict[str, str]) -> dict:
    """region -> PositionObservations of the laser-tracker collections of this cell in
    ``collections``: the one ``named`` for the region, '' the newest finished one (none: the
    region is left out). Refusal for a named one that is missing or another cell's."""
    sets = {}
    for region, given in named.items():
        found = _collection(collections, cell, results_cell, given, 'laser_tracker', region,
                            required=False)
        if found is not None:
            sets[region] = sources.observations(found)
    return sets


def _file_source(file: str, cell):
    """The Source of a goal's ``file``: a bag or a collection folder (ValueError else)."""
    from cobot_calib_ros.bags.errors import BagError
    kind = sources.recognise(file)
    if kind not in (sources.BAG, sources.COLLECTION):
        raise ValueError(f'{file}: a {kind} is identified offline: cobot-calib identify '
                         f'--source {file}; the goal\'s file is a bag or a collection folder')
    try:
        return sources.load_source(file, cell=cell)
    except BagError as e:
        raise ValueError(str(e)) from None


def _collection(collections, cell, results_cell, collection_id: str, source: str,
                region: str | None = None, required: bool = True):
    """The given collection of this cell, else the newest done one of ``source`` (and
    region); Refusal NO_DATA / FOREIGN_RESULT."""
    def foreign(meta: dict) -> Failure | None:
        return results_cell.problem(meta.get('cell', ''), meta.get('robot', ''))
    if collection_id:
        data = collections.load(check_id(collection_id))
        if data is None:
            raise Refusal(Failure(ErrorCode.NO_DATA, f'no readable collection '
                                  f'{collection_id!r} in {collections.directory}'))
        problem = foreign(data.meta)
        if problem is not None:
            raise Refusal(Failure(problem.code, (
                f'collection {collection_id} is not this cell\'s: {problem.message}; identify '
                'it on its own cell\'s suite (or offline: cobot-calib identify --source)')))
        return data
    for meta in collections.list_collections():
        if meta['source'] == source and meta['status'] == 'done' and foreign(meta) is None \
                and (region is None or meta.get('region') == region):
            return collections.load(meta['id'])
    if required:
        raise Refusal(Failure(ErrorCode.NO_DATA, (
            f'no finished {source} collection for {cell.robot} in '
            f'{collections.directory}; run collect_sphere_data first')))
    return None
