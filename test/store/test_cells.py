"""Results keyed by the cell they were made on (store.cells, issue 31 item 1), in the folder
store, SQLite and a real PostgreSQL alike: two robots' cells on one data dir each activate
only their own results, a record of another cell or robot is refused by name, and records
stored before the keying (5252a67's folder store, the database's cell 'default') are taken
by the cell of their robot, with their active choice, and said so."""
from __future__ import annotations

import itertools
import json
from pathlib import Path
import shutil

import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core.errors import ErrorCode, Refusal
from cobot_calib_ros.store.cells import LEGACY_CELL, ResultsCell
from cobot_calib_ros.store.database import Database
from cobot_calib_ros.store.repository import FolderRepository

STORE_5252A67 = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67'
_plants = itertools.count()


def _stored(kind: str) -> dict:
    return json.loads(next((STORE_5252A67 / kind).glob('*.json')).read_text())


def _frame(record_id: str, stamp_ns: int) -> dict:
    return {'id': record_id, 'stamp_ns': stamp_ns, 'method': 'rigid', 'inputs': {'n': 5},
            'result': {'rms': 1e-4}}


@pytest.fixture(params=['folder', 'sqlite', 'postgresql'])
def opener(request, tmp_path):
    """cell -> the repository of one data dir for that cell, on each backend (a PostgreSQL
    database of the session shared by all tests: cell names unique per test)."""
    plant = f'p{next(_plants)}_{id(request)}_'
    if request.param == 'folder':
        (tmp_path / 'calibrations').mkdir()         # a data dir of the folder store

        def open_folder(cell):
            return FolderRepository(tmp_path, cell)
        return open_folder
    url = (f'sqlite:///{tmp_path / "results.sqlite"}' if request.param == 'sqlite'
           else request.getfixturevalue('postgres_url'))

    def open_db(cell):
        if isinstance(cell, ResultsCell):
            cell = ResultsCell(plant + cell.name, cell.robot)
        return store.open(tmp_path, url, cell)
    return open_db


SAWYER, IIWA = ResultsCell('sawyer_close', 'sawyer'), ResultsCell('iiwa7_close', 'iiwa7')


def test_two_robots_cells_on_one_data_dir_activate_only_their_own_results(opener):
    sawyer = opener(SAWYER)
    assert sawyer.user_frames.save_and_activate(_frame('frame-sawyer', 1))
    hand_eye = {**_stored('hand_eye'), 'cell': sawyer.cell.name}
    assert sawyer.hand_eye.save_and_activate(hand_eye)
    sawyer_kinematics = {**_stored('kinematics'), 'id': 'lm-sawyer', 'robot': 'sawyer'}
    assert sawyer.kinematics.save_and_activate(sawyer_kinematics)
    iiwa = opener(IIWA)
    assert iiwa.user_frames.active() is None and iiwa.user_frames.history() == []
    assert iiwa.hand_eye.active() is None and iiwa.kinematics.active('sawyer') is None
    for history, record_id in ((iiwa.user_frames, 'frame-sawyer'),
                               (iiwa.kinematics, 'lm-sawyer')):
        with pytest.raises(Refusal, match=(
                rf"{record_id} is not this cell's: it was made in cell '\w*sawyer_close' on "
                r"the sawyer; this is cell '\w*iiwa7_close' on the iiwa7")):
            history.activate(record_id)
    with pytest.raises(Refusal, match='made on the sawyer; this is cell .* on the iiwa7') as e:
        iiwa.hand_eye.save(_stored('hand_eye') | {'robot': 'sawyer', 'cell': ''})
    assert e.value.failure.code == ErrorCode.FOREIGN_RESULT
    assert iiwa.user_frames.save_and_activate(_frame('frame-iiwa', 2))
    again = opener(SAWYER)                      # reopened: each keeps its own, as stored
    assert again.user_frames.active()['id'] == 'frame-sawyer'
    assert again.hand_eye.active()['id'] == hand_eye['id']
    assert again.kinematics.resolve('latest', 'sawyer')['id'] == 'lm-sawyer'
    frame = opener(IIWA).user_frames.active()
    assert (frame['id'], frame['cell'], frame['robot']) == (
        'frame-iiwa', iiwa.cell.name, 'iiwa7')
    assert {again.cell.name, iiwa.cell.name} <= set(again.cells())


def test_a_cell_name_used_again_with_another_robot_takes_none_of_its_results(opener):
    assert opener(ResultsCell('cell_07', 'sawyer')).user_frames.save_and_activate(
        _frame('frame-07', 1))
    other = opener(ResultsCell('cell_07', 'iiwa7'))
    assert other.user_frames.active() is None
    with pytest.raises(Refusal, match="made on the sawyer; this is cell '.*cell_07' on "
                                            'the iiwa7'):
        other.user_frames.get('frame-07')


def test_a_5252a67_folder_store_is_read_by_the_cell_of_each_record_s_robot(tmp_path):
    data = tmp_path / 'data'
    shutil.copytree(STORE_5252A67, data)
    store.open(data).user_frames.activate('20261125T150121.468359984Z-three_point')
    sawyer = store.open(data, cell=SAWYER)
    assert sawyer.user_frames.active()['id'] == '20261125T150121.468359984Z-three_point'
    assert any('2 record(s) stored before results were keyed by cell taken as cell '
               "'sawyer_close'" in w for w in sawyer.user_frames.warnings)
    assert sawyer.hand_eye.active()['id'] == _stored('hand_eye')['id']   # it named its cell
    assert sawyer.kinematics.resolve('latest', 'sawyer') is None
    with pytest.raises(Refusal, match="made on the iiwa7; this is cell 'sawyer_close' "
                                            'on the sawyer'):
        sawyer.kinematics.resolve(_stored('kinematics')['id'], 'sawyer')
    iiwa = store.open(data, cell=IIWA)
    assert iiwa.kinematics.resolve('latest', 'iiwa7')['id'] == _stored('kinematics')['id']
    assert iiwa.hand_eye.active() is None
    with pytest.raises(Refusal, match="made in cell 'sawyer_close'"):
        iiwa.hand_eye.get(_stored('hand_eye')['id'])
    # the cell's own choice over the legacy one, kept across a restart; the old one unchanged
    assert sawyer.user_frames.activate(None).record_id == '20261125T150121.300898935Z-rigid'
    assert store.open(data, cell=SAWYER).user_frames.active()['id'] == \
        '20261125T150121.300898935Z-rigid'
    assert store.open(data).user_frames.active()['id'] == \
        '20261125T150121.468359984Z-three_point'


@pytest.fixture
def legacy_rows(db_url):
    """The database of db_url, its rows of cell 'default' removed afterwards (the session's
    PostgreSQL is shared: other tests' cells would take them)."""
    yield db_url
    database = Database(db_url)
    results, selections = database.t.results, database.t.selections
    with database.engine.connect().execution_options(writing=True) as connection, \
            connection.begin():
        connection.execute(results.delete().where(results.c.cell == LEGACY_CELL))
        connection.execute(selections.delete().where(selections.c.cell == LEGACY_CELL))


def test_database_rows_from_before_the_keying_go_to_the_cell_of_their_robot(legacy_rows,
                                                                           tmp_path,
                                                                           monkeypatch):
    """What 85479bc stored from `up --cell sawyer_close` (cell 'default', the robot in the
    provenance) is the Sawyer cell's, not the iiwa's that `up --cell iiwa7_close` starts."""
    db_url = legacy_rows
    default_rows = store.open(tmp_path / 'old', db_url).user_frames       # no cell: 'default'
    monkeypatch.setenv('COBOT_CALIB_ROBOT', 'sawyer')
    name = f'legacy_{id(tmp_path)}'
    default_rows.save(_frame(f'{name}-a', 1))
    default_rows.save(_frame(f'{name}-b', 2))
    default_rows.activate(f'{name}-a')
    monkeypatch.delenv('COBOT_CALIB_ROBOT')
    iiwa = store.open(tmp_path / 'iiwa', db_url, IIWA).user_frames
    assert not {f'{name}-a', f'{name}-b'} & iiwa.ids()
    with pytest.raises(Refusal, match='made on the sawyer; this is cell .* on the iiwa7'):
        iiwa.get(f'{name}-a')
    sawyer = store.open(tmp_path / 'sawyer', db_url, ResultsCell(f'{name}_sawyer', 'sawyer'))
    assert sawyer.user_frames.active()['id'] == f'{name}-a'         # the legacy choice
    assert sawyer.user_frames.save_and_activate(_frame(f'{name}-c', 3))
    assert Database(db_url).rows(f'{name}_sawyer', 'user_frame')[0]['robot_model'] == 'sawyer'
    assert store.open(tmp_path, db_url, f'{name}_sawyer').user_frames.active()['id'] == \
        f'{name}-c'                             # a name alone: the robot its results name


def test_db_import_keeps_each_record_in_its_cell_with_its_choice(tmp_path):
    from cobot_calib_ros.store.importer import import_folder
    from cobot_calib_ros.store.repository import DatabaseRepository
    source = tmp_path / 'old'
    shutil.copytree(STORE_5252A67, source)
    folder_sawyer = FolderRepository(source, SAWYER)
    folder_sawyer.user_frames.save(_frame('frame-sawyer-2', 2))
    folder_sawyer.user_frames.activate('20261125T150121.468359984Z-three_point')
    target = DatabaseRepository(tmp_path / 'new', f'sqlite:///{tmp_path / "db.sqlite"}')
    import_folder(source, target)
    assert set(target.cells()) == {'default', 'sawyer_close'}
    sawyer = store.open(tmp_path / 'new', target.database.url, SAWYER)
    assert sawyer.user_frames.active() == folder_sawyer.user_frames.active()
    assert sawyer.user_frames.active()['id'] == '20261125T150121.468359984Z-three_point'
    assert [r['id'] for r in sawyer.user_frames.history()] == [
        r['id'] for r in FolderRepository(source, SAWYER).user_frames.history()]
    assert store.open(tmp_path / 'new', target.database.url, IIWA).kinematics.resolve(
        'latest', 'iiwa7')['id'] == _stored('kinematics')['id']
