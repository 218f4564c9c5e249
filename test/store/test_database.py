"""The results database (store.database) on SQLite and a real PostgreSQL: the folder store's
activation rules, cells kept apart, provenance, migrations = schema, atomic writes under
SIGKILL, and the import of a file store written by 5252a67 (issue 19 must-show 4)."""
from __future__ import annotations

import itertools
import json
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import pytest

from cobot_calib_ros import store
from cobot_calib_ros.store.calibrations import CalibrationStore
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.database import (Database, provenance_of, software_version,
                                            SQLITE_FILE)
from cobot_calib_ros.store.importer import import_folder
from cobot_calib_ros.store.repository import DatabaseRepository, FolderRepository
from cobot_calib_ros.store.trials import TrialStore

STORE_5252A67 = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67'
_cells = itertools.count()


@pytest.fixture
def cell():
    return f'cell_{next(_cells):02d}_{id(object())}'


def _record(record_id, stamp_ns, **extra):
    return {'id': record_id, 'stamp_ns': stamp_ns, 'method': 'rigid', 'inputs': {'n': 5},
            'result': {'rms': 1e-4}, **extra}


def test_activation_rules_are_the_folder_stores(db_url, cell, tmp_path):
    folder = FolderRepository(tmp_path / 'folder', ResultsCell(cell)).kinematics
    db = store.open(tmp_path / 'd', db_url, cell).kinematics
    steps = [('save', _record('k1', 1, robot='iiwa7')), ('save', _record('k2', 2, robot='iiwa7')),
             ('save', _record('s1', 3, robot='sawyer')), ('activate', 'k1'),
             ('save', _record('k3', 4, robot='iiwa7', gate_problem='residual 9 mm > 1 mm')),
             ('activate', 'k3'), ('retire', 'k2'), ('retire', 's1'), ('activate', 'k2')]
    for action, arg in steps:
        outcomes = [getattr(s, action)(arg) for s in (folder, db)]
        if action == 'activate':
            assert outcomes[0] == outcomes[1]
    for scope in ('iiwa7', 'sawyer', ''):
        assert folder.active(scope) == db.active(scope)
    reopened = store.open(tmp_path / 'd', db_url, cell).kinematics      # from the database
    assert reopened.active('iiwa7')['id'] == folder.active('iiwa7')['id'] == 'k2'
    assert reopened.active('sawyer') is None
    assert reopened.retired() == folder.retired() == {'s1'}
    assert reopened.rejected() == {'k3': 'residual 9 mm > 1 mm'}
    assert reopened.history() == folder.history()


def test_cells_are_kept_apart_and_provenance_is_stored(db_url, cell, tmp_path, monkeypatch):
    monkeypatch.setenv('COBOT_CALIB_ROBOT_SERIAL', 'SN-1234')
    monkeypatch.setenv('COBOT_CALIB_TEMPERATURE_C', '23.5')
    a = store.open(tmp_path / 'a', db_url, cell)
    b = store.open(tmp_path / 'b', db_url, cell + '_other')
    a.user_frames.save_and_activate(_record('f1', 10, kinematics='k-7'))
    assert b.user_frames.active() is None and b.user_frames.history() == []
    row, = Database(db_url).rows(cell, 'user_frame')
    assert (row['cell'], row['robot_serial'], row['temperature_c']) == (cell, 'SN-1234', 23.5)
    assert row['model_hash'] == provenance_of(_record('f1', 10, kinematics='k-7'),
                                              cell).model_hash != ''
    assert row['software_version'] == software_version() and json.loads(row['body'])['id'] == 'f1'


def test_the_migrations_build_exactly_the_schema(db_url):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext
    from cobot_calib_ros.store import schema
    from alembic.config import Config
    from alembic.script import ScriptDirectory
    from cobot_calib_ros.store.database import HEAD_REVISION
    config = Config()
    config.set_main_option('script_location', str(Path(schema.__file__).parent / 'migrations'))
    assert ScriptDirectory.from_config(config).get_current_head() == HEAD_REVISION
    engine = Database(db_url).engine
    with engine.connect() as connection:
        context = MigrationContext.configure(connection)
        assert context.get_current_revision() == HEAD_REVISION
        assert compare_metadata(context, schema.metadata) == []


def test_sqlite_is_the_default_of_a_new_data_dir_and_a_folder_store_stays_one(tmp_path,
                                                                             monkeypatch):
    monkeypatch.delenv('COBOT_CALIB_DB', raising=False)
    repo = store.open(tmp_path / 'new')
    assert isinstance(repo, DatabaseRepository)
    repo.hand_eye.save(_record('h1', 1))
    assert (tmp_path / 'new' / SQLITE_FILE).is_file()
    assert not (tmp_path / 'new' / 'hand_eye').exists()
    old = tmp_path / 'old'
    shutil.copytree(STORE_5252A67, old)
    assert isinstance(store.open(old), FolderRepository)       # until `db import`


KILL_MID_WRITE = '''
import sys
from cobot_calib_ros.store.database import Database, _write
db = Database(sys.argv[1])
results = db.t.results
with _write(db.engine) as connection, connection.begin():
    connection.execute(results.update().where(results.c.id == 'f1').values(body='{}'))
    connection.execute(results.delete().where(results.c.id == 'f0'))
    print('mid-write', flush=True)
    sys.stdin.read()              # killed here: nothing committed
'''


def test_a_kill_mid_write_leaves_the_previous_state(db_url, cell, tmp_path):
    repo = store.open(tmp_path, db_url, cell)
    repo.user_frames.save(_record('f0', 1))
    repo.user_frames.save_and_activate(_record('f1', 2))
    before = store.open(tmp_path, db_url, cell).user_frames.history()
    child = subprocess.Popen([sys.executable, '-c', KILL_MID_WRITE, db_url],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == 'mid-write'
    child.send_signal(signal.SIGKILL)
    child.wait()
    after = store.open(tmp_path, db_url, cell)
    assert after.user_frames.history() == before
    after.user_frames.save_and_activate(_record('f2', 3))      # and the database still works
    assert store.open(tmp_path, db_url, cell).user_frames.active()['id'] == 'f2'


def test_import_of_a_5252a67_file_store_keeps_every_record(db_url, cell, tmp_path):
    """Must-show 4: counts and values compared, kind by kind; importing twice duplicates
    nothing."""
    source = tmp_path / 'old'
    shutil.copytree(STORE_5252A67, source)
    CalibrationStore(source, 'calibrations').activate('20261125T150121.468359984Z-three_point')
    target = DatabaseRepository(tmp_path / 'new', db_url, ResultsCell(cell))
    report = import_folder(source, target)
    import_folder(source, target)
    assert report.counts == {'user_frame': 2, 'hand_eye': 1, 'kinematics': 1, 'tcp': 0,
                             'intrinsics': 0,
                             'trial': 1, 'collection': 0} and report.skipped == []
    folder = FolderRepository(source)
    imported = store.open(tmp_path / 'new', db_url, cell)
    for kind in ('user_frames', 'hand_eye', 'kinematics'):
        old, new = getattr(folder, kind), getattr(imported, kind)
        assert new.history() == old.history()                    # every key, every value
        assert len(Database(db_url).rows(cell, {'user_frames': 'user_frame'}.get(
            kind, kind))) == len(old.history())
        assert new.active(new.scope_of(old.history()[0])) == old.active(
            old.scope_of(old.history()[0]))
    assert imported.user_frames.active()['id'] == '20261125T150121.468359984Z-three_point'
    row, = Database(db_url).rows(cell, 'trial')
    body = json.loads(row['body'])
    csv = STORE_5252A67 / 'trials' / 'trial-1' / 'distances.csv'
    assert body['log'] == csv.read_text() and body['meta'] == TrialStore(
        STORE_5252A67).list_trials()[0]
    old_trial, new_trial = TrialStore(STORE_5252A67).load('trial-1'), imported.trials.load(
        'trial-1')
    assert (new_trial.distances.tobytes() == old_trial.distances.tobytes()
            and new_trial.meta == old_trial.meta)


def test_an_unreachable_database_is_a_storage_error(tmp_path):
    from cobot_calib_ros.store.database import DatabaseError
    with pytest.raises(OSError, match='database postgresql://nobody@127.0.0.1:1/none') as err:
        store.open(tmp_path, 'postgresql://nobody@127.0.0.1:1/none').user_frames.active()
    assert isinstance(err.value, DatabaseError)      # nodes answer STORAGE_FAILED, no crash
    assert 'secret' not in str(Database('postgresql://u:secret@h/db'))
