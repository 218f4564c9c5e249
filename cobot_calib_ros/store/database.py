"""The results database: every calibration and check of every cell, with provenance.

SQLAlchemy Core over SQLite (a file in the data dir, the embedded default) or PostgreSQL (one
server for a plant: ``postgresql://...``); the same schema on both, created and upgraded by
alembic (``store/migrations``, applied on first use of a URL in a process). Tables:

==============  ==============================================================================
``results``     one row per stored result: (cell, kind, id) key, scope (the robot for
                kinematics), stamp_ns, method, gate_problem, provenance columns (the robot
                in ``robot_model``), the record as JSON (``body``, the mapping the folder
                store writes); cell ``default``: rows stored before results were keyed by
                cell (store.cells)
``selections``  (cell, kind, scope) -> the chosen active id (only where it is not the newest)
``retired``     (cell, kind, id) of retired records
==============  ==============================================================================

Kinds: ``user_frame``, ``hand_eye``, ``kinematics``, ``tcp`` (scope: the tool), ``intrinsics``
(scope: the camera), ``check`` (quick health checks), and
``trial`` / ``collection`` (a trial's or a kinematic-data collection's metadata and rows, as
imported by ``cobot-calib db import``; live measurement logs stay append-only files).

Atomicity: a save is one transaction (the row and nothing else), a change of the active choice
another: a process killed mid-write leaves the previous state (test_database). SQLite runs in
WAL mode with ``synchronous=FULL`` and takes the write lock at the start of a write
(``BEGIN IMMEDIATE``), so concurrent writers wait (busy timeout) instead of failing.

:class:`DbCalibrationHistory` is a store.calibrations.CalibrationStore whose records and
choices live in the database: the activation rules and the gate are that class's, unchanged.
"""
from __future__ import annotations

from collections.abc import Mapping
import contextlib
import functools
from dataclasses import asdict, dataclass
import hashlib
import json
import os
from pathlib import Path
import re
import threading
import time
from typing import Any

from cobot_calib_ros.store.calibrations import _record_problem, CalibrationStore
from cobot_calib_ros.store.cells import LEGACY_CELL, ResultsCell
from cobot_calib_ros.store.files import to_plain
from cobot_calib_ros.store.kinematics import KinematicHistory
from cobot_calib_ros.store.renamed import with_current_names

SQLITE_FILE = 'cobot_calib.sqlite'
DB_ENV = 'COBOT_CALIB_DB'            # a database URL for every node and command
BUSY_TIMEOUT_S = 60.0
HEAD_REVISION = '0001'        # the newest of store/migrations/versions (test_database)
KINDS = ('user_frame', 'hand_eye', 'kinematics', 'tcp', 'intrinsics', 'check', 'trial',
         'collection')
PROVENANCE_ENV = {'robot_model': 'COBOT_CALIB_ROBOT', 'robot_serial': 'COBOT_CALIB_ROBOT_SERIAL',
                  'bag_sha256': 'COBOT_CALIB_BAG_SHA256',
                  'temperature_c': 'COBOT_CALIB_TEMPERATURE_C'}

_engines: dict[str, Any] = {}
_engines_lock = threading.Lock()


@dataclass(frozen=True)
class Provenance:
    """Where a result comes from. ``model_hash``: sha256 (16 hex) of the kinematic model the
    result was measured with (robot model and calibration id, or the parameters of a kinematic
    calibration itself); ``bag_sha256`` when the result comes from a replayed bag."""

    cell: str
    robot_model: str = ''
    robot_serial: str = ''
    model_hash: str = ''
    software_version: str = ''
    bag_sha256: str = ''
    temperature_c: float | None = None


def software_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version('cobot_calib_ros')
    except PackageNotFoundError:
        return 'unknown'


def provenance_of(record: Mapping[str, Any], cell: str,
                  environ: Mapping[str, str] = os.environ) -> Provenance:
    """The provenance of ``record``: its own ``provenance`` mapping where given (an imported or
    replayed record), else the record's robot, the environment (COBOT_CALIB_ROBOT, _SERIAL,
    _BAG_SHA256, _TEMPERATURE_C) and this software's version."""
    given = dict(record.get('provenance') or {})
    values = {key: environ.get(name, '') for key, name in PROVENANCE_ENV.items()}
    robot = str(record.get('robot') or values['robot_model'])
    if 'params' in record.get('result', {}):
        identity = json.dumps(to_plain(record['result']['params']))
    else:
        identity = f'{robot}:{record.get("kinematics") or "nominal"}'
    temperature = given.get('temperature_c', values['temperature_c'])
    return Provenance(
        cell=cell, robot_model=str(given.get('robot_model', robot)),
        robot_serial=str(given.get('robot_serial', values['robot_serial'])),
        model_hash=str(given.get('model_hash',
                                 hashlib.sha256(identity.encode()).hexdigest()[:16])),
        software_version=str(given.get('software_version', software_version())),
        bag_sha256=str(given.get('bag_sha256', values['bag_sha256'])),
        temperature_c=None if temperature in (None, '') else float(temperature))


def _hide_password(url: str) -> str:
    return re.sub(r'://([^:/@]+):[^@]*@', r'://\1:***@', url)


def sqlite_url(data_dir: Path) -> str:
    return f'sqlite:///{Path(data_dir).resolve() / SQLITE_FILE}'


def engine_for(url: str):
    """The process's engine of ``url``, its schema upgraded to the newest migration."""
    with _engines_lock:
        engine = _engines.get(url)
        if engine is None:
            engine = _create_engine(url)
            upgrade(engine)
            _engines[url] = engine
        return engine


def _create_engine(url: str):
    import sqlalchemy as sa
    if not url.startswith('sqlite'):
        url = url.replace('postgresql://', 'postgresql+psycopg://', 1)
        return sa.create_engine(url, pool_pre_ping=True, pool_size=2, max_overflow=4)
    path = url.removeprefix('sqlite:///')
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    engine = sa.create_engine(url, connect_args={'timeout': BUSY_TIMEOUT_S})

    @sa.event.listens_for(engine, 'connect')
    def _on_connect(dbapi_connection, _record):
        dbapi_connection.isolation_level = None      # we issue BEGIN ourselves (below)
        cursor = dbapi_connection.cursor()
        cursor.execute('PRAGMA journal_mode=WAL')
        cursor.execute('PRAGMA synchronous=FULL')
        cursor.execute(f'PRAGMA busy_timeout={int(BUSY_TIMEOUT_S * 1000)}')
        cursor.close()

    @sa.event.listens_for(engine, 'begin')
    def _on_begin(connection):
        connection.exec_driver_sql('BEGIN IMMEDIATE' if connection.get_execution_options().get(
            'writing') else 'BEGIN')

    return engine


def prepare(url: str) -> None:
    """Bring the database at ``url`` to the newest migration and let it go: what a launcher
    does before its nodes start, which would otherwise each run the migrations of a new data
    dir at once (~0.15 s of CPU apiece)."""
    engine = _create_engine(url)
    try:
        upgrade(engine)
    finally:
        engine.dispose()


def upgrade(engine) -> None:
    """Apply the alembic migrations up to the newest (store/migrations), unless the database
    is there already (a one-row read: alembic itself costs ~1 s of CPU per process)."""
    if current_revision(engine) == HEAD_REVISION:
        return
    from alembic import command
    from alembic.config import Config
    config = Config()
    config.set_main_option('script_location', str(Path(__file__).parent / 'migrations'))
    with engine.connect().execution_options(writing=True) as connection:
        if connection.dialect.name == 'postgresql':   # many cells' first use at once
            connection.exec_driver_sql('SELECT pg_advisory_xact_lock(191919)')
        config.attributes['connection'] = connection
        command.upgrade(config, 'head')
        connection.commit()


def current_revision(engine) -> str:
    """The alembic revision the database is at ('' for a new database)."""
    import sqlalchemy as sa
    with engine.connect() as connection:
        if not sa.inspect(connection).has_table('alembic_version'):
            return ''
        return connection.exec_driver_sql('SELECT version_num FROM alembic_version').scalar() \
            or ''


def _write(engine):
    """A write transaction (SQLite: the write lock taken at BEGIN)."""
    return engine.connect().execution_options(writing=True)


class DatabaseError(OSError):
    """The database could not be reached or written: an OSError, as a file store's failure is,
    so the nodes' storage error handling covers both (STORAGE_FAILED)."""


@contextlib.contextmanager
def _as_storage_error(url: str):
    import sqlalchemy.exc
    try:
        yield
    except sqlalchemy.exc.SQLAlchemyError as exc:
        raise DatabaseError(f'database {_hide_password(url)}: {" ".join(str(exc).split())[:300]}') from exc


class Database:
    """One database URL: the tables, the rows of one cell. Failures raise DatabaseError."""

    def __init__(self, url: str) -> None:
        self.url = url

    @functools.cached_property
    def engine(self):
        """Made on first use: a node that opens its repository at start does not pay for
        SQLAlchemy until it reads or writes."""
        with _as_storage_error(self.url):
            return engine_for(self.url)

    @functools.cached_property
    def t(self):
        from cobot_calib_ros.store import schema
        return schema

    def __repr__(self) -> str:
        return f'Database({_hide_password(self.url)!r})'

    def put(self, cell: str, kind: str, plain: Mapping[str, Any], scope: str = '') -> None:
        """Insert or replace one result row, in one transaction."""
        prov = provenance_of(plain, cell)
        row = {'cell': cell, 'kind': kind, 'id': plain['id'], 'scope': scope,
               'stamp_ns': int(plain['stamp_ns']), 'method': str(plain.get('method', '')),
               'gate_problem': str(plain.get('gate_problem') or ''),
               **{k: v for k, v in asdict(prov).items() if k != 'cell'},
               'body': json.dumps(plain), 'written_ns': time.time_ns()}
        results = self.t.results
        key = ((results.c.cell == cell) & (results.c.kind == kind)
               & (results.c.id == plain['id']))
        with _as_storage_error(self.url), _write(self.engine) as connection, \
                connection.begin():
            if connection.execute(results.update().where(key).values(**row)).rowcount == 0:
                connection.execute(results.insert().values(**row))

    def rows(self, cell: str | None, kind: str, since_ns: int = 0) -> list[dict[str, Any]]:
        """(provenance columns + body) of one cell's results of ``kind`` (None: every
        cell's), oldest first."""
        results = self.t.results
        which = (results.c.kind == kind) & (results.c.stamp_ns >= since_ns)
        if cell is not None:
            which = which & (results.c.cell == cell)
        query = results.select().where(which).order_by(results.c.stamp_ns, results.c.id)
        with _as_storage_error(self.url), self.engine.connect() as connection:
            return [dict(r._mapping) for r in connection.execute(query)]

    def cells(self) -> dict[str, list[str]]:
        """{cell: the robots its results were made on ('' : not recorded)}."""
        import sqlalchemy as sa
        results = self.t.results
        cells: dict[str, list[str]] = {}
        with _as_storage_error(self.url), self.engine.connect() as connection:
            for cell, robot in connection.execute(
                    sa.select(results.c.cell, results.c.robot_model).distinct()
                    .order_by(results.c.cell, results.c.robot_model)):
                cells.setdefault(cell, []).append(robot)
        return cells

    def find(self, kind: str, record_id: str) -> list[tuple[str, str]]:
        """(cell, robot) of every row of ``kind`` with this id, whichever cell stored it."""
        results = self.t.results
        query = (results.select().with_only_columns(results.c.cell, results.c.robot_model)
                 .where((results.c.kind == kind) & (results.c.id == record_id)))
        with _as_storage_error(self.url), self.engine.connect() as connection:
            return [(r.cell, r.robot_model) for r in connection.execute(query)]

    def selection(self, cell: str, kind: str) -> tuple[dict[str, str], list[str]]:
        s, r = self.t.selections, self.t.retired
        with _as_storage_error(self.url), self.engine.connect() as connection:
            chosen = {row.scope: row.active_id for row in connection.execute(
                s.select().where((s.c.cell == cell) & (s.c.kind == kind)))}
            retired = sorted(row.id for row in connection.execute(
                r.select().where((r.c.cell == cell) & (r.c.kind == kind))))
        return chosen, retired

    def set_selection(self, cell: str, kind: str, chosen: Mapping[str, str],
                      retired: frozenset[str]) -> None:
        """Replace the choices and retired ids of (cell, kind), in one transaction."""
        s, r = self.t.selections, self.t.retired
        with _as_storage_error(self.url), _write(self.engine) as connection, \
                connection.begin():
            connection.execute(s.delete().where((s.c.cell == cell) & (s.c.kind == kind)))
            connection.execute(r.delete().where((r.c.cell == cell) & (r.c.kind == kind)))
            if chosen:
                connection.execute(s.insert(), [
                    {'cell': cell, 'kind': kind, 'scope': scope, 'active_id': record_id}
                    for scope, record_id in chosen.items()])
            if retired:
                connection.execute(r.insert(), [{'cell': cell, 'kind': kind, 'id': record_id}
                                                for record_id in sorted(retired)])


class DbCalibrationHistory(CalibrationStore):
    """A calibration history of one cell and kind in the database, with the activation rules
    of :class:`CalibrationStore` (whose records it reads once, then serves from memory, as
    the folder store: open the repository again to see another process's writes).
    ``cell``: whose rows (None: every cell's, writing as cell ``default``: the store as
    before results were keyed by cell);
    ``directory``: where files that go beside a record are written (kinematics' YAML, URDF)."""

    def __init__(self, database: Database, cell: ResultsCell | None, kind: str,
                 data_dir: Path, subdir: str, scope_key: str = '', **kwargs) -> None:
        super().__init__(data_dir, subdir, scope_key=scope_key, cell=cell, **kwargs)
        self.database, self.kind = database, kind
        self.cell_name = cell.name if cell else LEGACY_CELL

    def __str__(self) -> str:
        return f'{_hide_password(self.database.url)} (cell {self.cell_name}, {self.kind})'

    def _put(self, plain: dict[str, Any]) -> str:
        """Write a checked record in one transaction; returns where:
        '<url>#<cell>/<kind>/<id>'."""
        self.database.put(self.cell_name, self.kind, plain, self.scope_of(plain))
        self._index()[plain['id']] = plain
        return f'{_hide_password(self.database.url)}#{self.cell_name}/{self.kind}/{plain["id"]}'

    def _stored(self):
        """The rows of this cell, and the legacy ones (cell ``default``) for a cell to take:
        (record, cell: '' for legacy, robot: the record's, else its row's robot_model)."""
        cells = (None,) if self.cell is None else tuple(dict.fromkeys((self.cell_name,
                                                                        LEGACY_CELL)))
        for cell in cells:
            for row in self.database.rows(cell, self.kind):
                record = with_current_names(json.loads(row['body']))
                problem = _record_problem(record)
                if problem is not None:
                    self._warn(f'{self}: {row["id"]} skipped, {problem.message}')
                    continue
                robot = str(record.get('robot') or row['robot_model'] or '')
                yield record, '' if row['cell'] == LEGACY_CELL else row['cell'], robot

    def _elsewhere(self, record_id: str) -> str:
        why = super()._elsewhere(record_id)
        if why or self.cell is None:
            return why
        return next((why.message for cell, robot in self.database.find(self.kind, record_id)
                     if (why := self.cell.problem(cell, robot)) is not None), '')

    def _write_selection(self, kept: dict[str, str], retired: frozenset[str]) -> None:
        self.database.set_selection(self.cell_name, self.kind, kept, retired)

    def _stored_selections(self):
        def stored(cell: str):
            chosen, retired = self.database.selection(cell, self.kind)
            return {'active_ids': chosen, 'retired': retired}, ''
        legacy = stored(LEGACY_CELL) if self.cell is not None else (None, '')
        return stored(self.cell_name), legacy


class DbKinematicStore(KinematicHistory, DbCalibrationHistory):
    """Kinematic calibrations in the database; their YAML and URDF files in the data dir."""

    def __init__(self, database: Database, cell: ResultsCell | None, data_dir: Path) -> None:
        super().__init__(database, cell, 'kinematics', data_dir, 'kinematics',
                         scope_key='robot')
