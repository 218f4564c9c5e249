"""One repository of everything the suite stores, behind one factory: ``store.open(data_dir)``.

Two implementations: :class:`DatabaseRepository` (store.database: SQLite in the data dir by
default, or PostgreSQL; calibrations and checks as rows) and :class:`FolderRepository` (JSON
files, what a data dir written before the database holds until `cobot-calib db import`).
Trials and collections are append-only files in the data dir in both.

Nodes, the CLI and the API get their stores from :func:`open` (never by building a store class
themselves), so a second implementation (a history database) can replace the folder one in one
place. A :class:`Repository` has one history per calibration kind and the two measurement logs:

=====================  ======================  ==================================================
attribute              kind (store.records)    activation scope
=====================  ======================  ==================================================
``user_frames``        UserFrameRecord         one active per cell
``hand_eye``           HandEyeRecord           one active per cell
``kinematics``         KinematicRecord         one active per cell and robot
``tcp``                TcpRecord               one active per cell and tool
``intrinsics``         IntrinsicsRecord        one active per cell and camera
``checks``             check_record            (none: quick health checks are never activated)
``trials``             trial.yaml + readings   (none: trials are not activated)
``collections``        collection + rows       (none)
=====================  ======================  ==================================================

Keyed by cell (store.cells): ``store.open(data_dir, db, cell)`` with the cell the results
are made on (a ResultsCell: name and robot; nodes give theirs, ResultsCell.of); its histories
hold that cell's records only, every record it saves carries the cell's name and robot, and
a record of another cell or robot is refused by name. Many cells share one data dir or one
database; ``cells()`` names those with results. With no cell: the store as it was before
results were keyed (every cell's records, one active per kind and scope among them; what
it saves names no cell): for readers that look a record up by id, and old data dirs.

Activation and its gate (the one way a calibration becomes active)::

    outcome = repo.hand_eye.save_and_activate(record)   # record: a store.records record
    if not outcome:                                     # Activation, falsy if not active
        log(outcome.reason)                             # e.g. 'hand_eye-... is rejected
                                                        # (residual 14.5 mm > 0.2 mm ...)'

A record passes its gate when its ``gate_problem`` is '' (the builder of the record sets it
with its kind's criterion; a history may also be given a ``gate`` callable, record -> problem).
A record that fails is stored, stays in the history and in ``rejected()``, and never becomes
active: ``activate`` returns ``Activation(active=False, reason=...)`` and changes nothing, and
the default active record (the newest) skips it. ``activate(id)`` of a record that passes makes
it the active one of its scope; ``retire(id)`` keeps it in the history but never active.

Reads: a history reads its directory once and then serves from memory (one writer per
directory). A reader of another node's results (the user frame for the hand-eye, the hand-eye
for the landmark views, the kinematics for the solver and the trials) opens the repository
again for each use, so it sees what the writer stored since.
"""
from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
import os
from pathlib import Path
from typing import Any, Protocol

from cobot_calib_ros.store.calibrations import Activation, CalibrationStore
from cobot_calib_ros.store.cells import LEGACY_CELL, ResultsCell
from cobot_calib_ros.store.collections import CollectionStore
from cobot_calib_ros.store.kinematics import KinematicStore
from cobot_calib_ros.store.trials import TrialStore

__all__ = ['Activation', 'CalibrationHistory', 'DatabaseRepository', 'FolderRepository',
           'Repository', 'database_url', 'open']


class CalibrationHistory(Protocol):
    """The calibration records of one kind, and which one is active (per scope)."""

    def save(self, record) -> Any: ...
    def save_and_activate(self, record) -> Activation: ...
    def get(self, record_id: str) -> dict[str, Any] | None: ...
    def history(self, max_count: int = 0) -> list[dict[str, Any]]: ...
    def active(self, scope: str = '') -> dict[str, Any] | None: ...
    def activate(self, record_id: str | None, scope: str = '') -> Activation: ...
    def retire(self, record_id: str) -> None: ...
    def retired(self) -> frozenset[str]: ...
    def rejected(self) -> Mapping[str, str]: ...


class Repository(Protocol):
    """Everything the suite stores for one cell (see the module docstring)."""

    root: Path
    cell: ResultsCell | None

    def cells(self) -> dict[str, list[str]]: ...
    @property
    def user_frames(self) -> CalibrationHistory: ...
    @property
    def hand_eye(self) -> CalibrationHistory: ...
    @property
    def kinematics(self) -> KinematicStore: ...
    @property
    def tcp(self) -> CalibrationHistory: ...
    @property
    def intrinsics(self) -> CalibrationHistory: ...
    @property
    def trials(self) -> TrialStore: ...
    @property
    def collections(self) -> CollectionStore: ...
    @property
    def checks(self) -> CalibrationHistory: ...


class _MeasurementLogs:
    """Trials and sphere collections: append-only files under ``root`` (each reading fsynced
    as it comes) in every implementation."""
    root: Path

    @cached_property
    def trials(self) -> TrialStore:
        return TrialStore(self.root)

    @cached_property
    def collections(self) -> CollectionStore:
        return CollectionStore(self.root)


class FolderRepository(_MeasurementLogs):
    """The folder implementation: JSON / YAML / CSV files under ``root`` (store.files), the
    records of every cell side by side (each names its cell)."""

    def __init__(self, root: Path, cell: ResultsCell | None = None) -> None:
        self.root, self.cell = Path(root), cell

    @cached_property
    def user_frames(self) -> CalibrationStore:
        return CalibrationStore(self.root, 'calibrations', cell=self.cell)

    @cached_property
    def hand_eye(self) -> CalibrationStore:
        return CalibrationStore(self.root, 'hand_eye', cell=self.cell)

    @cached_property
    def kinematics(self) -> KinematicStore:
        return KinematicStore(self.root, self.cell)

    @cached_property
    def tcp(self) -> CalibrationStore:
        return CalibrationStore(self.root, 'tcp', scope_key=TCP_SCOPE, cell=self.cell)

    @cached_property
    def intrinsics(self) -> CalibrationStore:
        return CalibrationStore(self.root, 'intrinsics', scope_key='camera', cell=self.cell)

    @cached_property
    def checks(self) -> CalibrationStore:
        """Quick health checks (cli check): results like calibrations, never activated."""
        return CalibrationStore(self.root, 'checks', cell=self.cell)

    def cells(self) -> dict[str, list[str]]:
        """{cell: the robots its results were made on ('' : not recorded)}; records stored
        before results were keyed by cell are cell 'default'."""
        cells: dict[str, set[str]] = {}
        for subdir in (*FOLDER_RESULTS, 'checks'):
            for _, cell, robot in CalibrationStore(self.root, subdir)._stored():
                cells.setdefault(cell or LEGACY_CELL, set()).add(robot)
        return {cell: sorted(robots) for cell, robots in sorted(cells.items())}

    def __repr__(self) -> str:
        return f'FolderRepository({str(self.root)!r}, cell={self.cell!r})'


class DatabaseRepository(_MeasurementLogs):
    """The database implementation (store.database): one cell's calibrations and checks as
    rows of a SQLite file or a PostgreSQL server; the measurement logs (trials, collections)
    stay append-only files under ``root`` (each reading fsynced as it comes)."""

    def __init__(self, root: Path, url: str, cell: ResultsCell | None = None) -> None:
        from cobot_calib_ros.store.database import Database
        self.root, self.cell = Path(root), cell
        self.database = Database(url)

    @property
    def cell_name(self) -> str:
        """The cell of this repository's rows ('default': before keying by cell)."""
        return self.cell.name if self.cell else LEGACY_CELL

    def cells(self) -> dict[str, list[str]]:
        return self.database.cells()

    def _history(self, kind: str, subdir: str, scope_key: str = ''):
        from cobot_calib_ros.store.database import DbCalibrationHistory
        return DbCalibrationHistory(self.database, self.cell, kind, self.root, subdir,
                                    scope_key=scope_key)

    @cached_property
    def user_frames(self):
        return self._history('user_frame', 'calibrations')

    @cached_property
    def hand_eye(self):
        return self._history('hand_eye', 'hand_eye')

    @cached_property
    def checks(self):
        """Quick health checks (cli check): results like calibrations, never activated."""
        return self._history('check', 'checks')

    @cached_property
    def tcp(self):
        return self._history('tcp', 'tcp', TCP_SCOPE)

    @cached_property
    def intrinsics(self):
        return self._history('intrinsics', 'intrinsics', scope_key='camera')

    @cached_property
    def kinematics(self):
        from cobot_calib_ros.store.database import DbKinematicStore
        return DbKinematicStore(self.database, self.cell, self.root)

    def __repr__(self) -> str:
        return f'DatabaseRepository({str(self.root)!r}, {self.database!r}, cell={self.cell!r})'


FOLDER_RESULTS = ('calibrations', 'hand_eye', 'kinematics', 'tcp', 'intrinsics')
TCP_SCOPE = 'tool'         # a TCP is active per tool


def database_url(data_dir: Path | str, db: str | None = None) -> str:
    """The database of ``data_dir``: ``db`` when given, else $COBOT_CALIB_DB, else the data
    dir's own SQLite file; '' for a data dir that holds a folder store and no database (one
    written before the database: it stays a folder store until `cobot-calib db import`)."""
    from cobot_calib_ros.store.database import DB_ENV, SQLITE_FILE, sqlite_url
    url = db or os.environ.get(DB_ENV, '')
    if url:
        return url
    root = Path(data_dir)
    if not (root / SQLITE_FILE).exists() and any((root / d).is_dir() for d in FOLDER_RESULTS):
        return ''
    return sqlite_url(root)


def open(data_dir: Path | str, db: str | None = None,   # noqa: A001 (store.open, as io.open)
         cell: ResultsCell | str | None = None) -> Repository:
    """The repository of ``data_dir`` (a resolved data directory, see paths.data_dir) for
    ``cell`` (a ResultsCell; a name alone: its robot is the one its results were made on):
    its database (:func:`database_url`), or the folder store of a data dir written before the
    database. No cell: the store as before results were keyed by cell."""
    url = database_url(data_dir, db)

    def build(for_cell: ResultsCell | None) -> Repository:
        if not url:
            return FolderRepository(Path(data_dir), for_cell)
        return DatabaseRepository(Path(data_dir), url, for_cell)
    given = ResultsCell(cell) if isinstance(cell, str) else cell
    repo = build(given)
    if given is not None and not given.robot:
        robots = [r for r in repo.cells().get(given.name, []) if r]
        if len(robots) == 1:
            repo = build(ResultsCell(given.name, robots[0]))
    return repo
