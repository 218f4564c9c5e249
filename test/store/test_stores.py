"""Durable calibration records and trial logs: atomic writes, crashes, restarts, resume."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.store import files
from cobot_calib_ros.core.repeatability import point_statistics
from cobot_calib_ros.store.calibrations import CalibrationStore
from cobot_calib_ros.store.files import atomic_write_bytes, atomic_write_text
from cobot_calib_ros.store.trials import CSV_HEADER, TrialStore

MM = 1e-3  # [m]
POINTS = ['P1', 'P2', 'P3']


def _record(record_id: str, stamp_ns: int, **extra) -> dict:
    return {'id': record_id, 'stamp_ns': stamp_ns, 'method': 'five_points',
            'inputs': {'points': ['P1', 'P2']}, 'result': {'rms_error': 1e-4}, **extra}


def test_atomic_write_replaces_content_and_leaves_no_temp_file(tmp_path):
    target = tmp_path / 'result.yaml'
    atomic_write_text(target, 'first\n')
    atomic_write_text(target, 'second\n')
    assert target.read_text() == 'second\n'
    atomic_write_bytes(target, b'\x00\x01')
    assert target.read_bytes() == b'\x00\x01'
    assert sorted(os.listdir(tmp_path)) == ['result.yaml']


def test_failed_atomic_write_keeps_old_content_and_removes_temp(tmp_path, monkeypatch):
    target = tmp_path / 'result.yaml'
    atomic_write_text(target, 'old\n')

    def crash(src, dst):
        raise OSError('disk gone')

    monkeypatch.setattr(files.os, 'replace', crash)
    with pytest.raises(OSError, match='disk gone'):
        atomic_write_text(target, 'new\n')
    assert target.read_text() == 'old\n'
    assert sorted(os.listdir(tmp_path)) == ['result.yaml']


def test_restart_sees_latest_calibration_and_history_order(tmp_path):
    store = CalibrationStore(tmp_path)
    for record_id, stamp in [('cal-b', 2_000), ('cal-a', 1_000), ('cal-c', 3_000)]:
        path = store.save(_record(record_id, stamp))
        assert path == tmp_path / 'calibrations' / f'{record_id}.json'
    restarted = CalibrationStore(tmp_path)
    assert restarted.latest()['id'] == 'cal-c'
    assert [r['id'] for r in restarted.history()] == ['cal-c', 'cal-b', 'cal-a']
    assert [r['id'] for r in restarted.history(max_count=2)] == ['cal-c', 'cal-b']
    assert restarted.get('cal-a') == _record('cal-a', 1_000)
    assert restarted.get('cal-z') is None
    assert restarted.warnings == []


def test_saving_an_id_again_replaces_the_record(tmp_path):
    store = CalibrationStore(tmp_path)
    store.save(_record('cal', 1))
    store.save(_record('cal', 2))
    assert [r['stamp_ns'] for r in CalibrationStore(tmp_path).history()] == [2]


def test_numpy_values_are_stored_as_plain_json(tmp_path):
    store = CalibrationStore(tmp_path)
    transform = np.eye(4)
    transform[:3, 3] = [0.5, -0.25, 0.125]
    store.save(_record('cal', np.int64(7), result={'T_base_user': transform,
                                                   'rms_error': np.float64(2e-4)}))
    loaded = CalibrationStore(tmp_path).get('cal')
    assert loaded['stamp_ns'] == 7
    np.testing.assert_array_equal(np.array(loaded['result']['T_base_user']), transform)
    assert loaded['result']['rms_error'] == 2e-4


def test_corrupt_partial_and_leftover_files_are_skipped_with_warnings(tmp_path):
    store = CalibrationStore(tmp_path)
    store.save(_record('good', 1))
    directory = tmp_path / 'calibrations'
    (directory / 'broken.json').write_text('{"id": "broken", "stamp_ns": [2,\n')  # crash
    (directory / 'list.json').write_text('[1, 2]\n')
    (directory / 'renamed.json').write_text(
        (directory / 'good.json').read_text().replace('"stamp_ns": 1', '"stamp_ns": 9'))
    (directory / 'partial.json').write_text('{"id": "partial", "stamp_ns": 3}\n')
    (directory / '.newest.json.x1y2.tmp').write_text('{"id": "newest", "stamp_ns": 99, "me')
    restarted = CalibrationStore(tmp_path)
    assert [r['id'] for r in restarted.history()] == ['good']
    assert restarted.get('broken') is None
    joined = '\n'.join(restarted.warnings)
    for name in ('broken.json', 'list.json', 'renamed.json', 'partial.json'):
        assert name in joined
    assert '.newest' not in joined
    assert len(restarted.warnings) == 4  # the same problem is reported once


@pytest.mark.parametrize('record', [
    {'id': 'x', 'stamp_ns': 1},                        # missing keys
    _record('../escape', 1),                           # path traversal
    _record('x', 1.5),                                 # stamp not an int
    _record('x', True),
])
def test_invalid_records_are_refused(tmp_path, record):
    with pytest.raises(ValueError):
        CalibrationStore(tmp_path).save(record)


def test_empty_store(tmp_path):
    store = CalibrationStore(tmp_path / 'nowhere')
    assert store.latest() is None
    assert store.history() == []
    with pytest.raises(ValueError):
        store.get('../x')


def _new_trial(root: Path, trial_id: str = 'trial-1', created: int = 100) -> TrialStore:
    trials = TrialStore(root)
    trials.create(trial_id, method='five_points', axis='z', layout='close',
                  point_names=POINTS, cycles_total=4, stamp_ns=created)
    return trials


def _fill(trials: TrialStore, cycles: int, extra_points: int = 0) -> None:
    """Readings 1.0 + 0.01 * (cycle + point) mm for whole cycles, then a partial one."""
    cells = [(c, p) for c in range(cycles) for p in range(len(POINTS))]
    cells += [(cycles, p) for p in range(extra_points)]
    for cycle, point in cells:
        trials.append('trial-1', cycle, point, (1.0 + 0.01 * (cycle + point)) * MM,
                      stamp_ns=1_000 + cycle * 10 + point)


def test_trial_files_and_metadata(tmp_path):
    _new_trial(tmp_path)
    trial_dir = tmp_path / 'trials' / 'trial-1'
    assert sorted(os.listdir(trial_dir)) == ['distances.csv', 'trial.yaml']
    assert (trial_dir / 'distances.csv').read_text() == CSV_HEADER + '\n'
    meta = TrialStore(tmp_path).load('trial-1').meta
    assert meta == {'id': 'trial-1', 'method': 'five_points', 'axis': 'z', 'layout': 'close',
                    'point_names': POINTS, 'cycles_total': 4, 'status': 'running',
                    'created_ns': 100, 'updated_ns': 100}
    with pytest.raises(FileExistsError):
        _new_trial(tmp_path)


def test_resume_right_after_a_partial_cycle(tmp_path):
    _fill(_new_trial(tmp_path), cycles=2, extra_points=2)
    data = TrialStore(tmp_path).load('trial-1')
    assert data.resume == (2, 2)
    assert data.missing == ()
    assert np.isfinite(data.distances).sum() == 8
    assert data.distances[1, 2] == pytest.approx(1.03 * MM)
    assert np.isnan(data.distances[2, 2]) and np.isnan(data.distances[:, 3]).all()
    assert point_statistics(data.distances).cycles == 2


def test_resume_at_start_and_none_when_complete(tmp_path):
    trials = _new_trial(tmp_path)
    assert TrialStore(tmp_path).load('trial-1').resume == (0, 0)
    _fill(trials, cycles=4)
    data = TrialStore(tmp_path).load('trial-1')
    assert data.resume is None
    assert np.isfinite(data.distances).all()


def test_eq15_correction_is_logged_and_loaded(tmp_path):
    trials = _new_trial(tmp_path)
    # Commanded F - FF (closer) with FF = 1.3 mm, probe read 1.25 mm -> 2.55 mm.
    corrected = trials.append('trial-1', 0, 0, 1.25 * MM, 1.3 * MM, 'closer', stamp_ns=5)
    assert corrected == pytest.approx(2.55 * MM)
    # Commanded F + FF (away) with FF = 1.1 mm, probe read 1.22 mm -> 0.12 mm.
    trials.append('trial-1', 0, 1, 1.22 * MM, 1.1 * MM, 'away', stamp_ns=6)
    data = TrialStore(tmp_path).load('trial-1')
    np.testing.assert_allclose(data.distances[:2, 0], [2.55 * MM, 0.12 * MM], atol=1e-15)
    np.testing.assert_allclose(data.raw_distances[:2, 0], [1.25 * MM, 1.22 * MM], atol=0)
    lines = _csv(tmp_path).read_text().splitlines()
    assert lines[1] == f'0,0,P1,{1.25 * MM!r},{1.3 * MM!r},closer,{corrected!r},5'
    assert lines[2].split(',')[5:6] == ['away']


def _csv(root: Path) -> Path:
    return root / 'trials' / 'trial-1' / 'distances.csv'


def test_writes_are_fsynced(tmp_path, monkeypatch):
    trials = _new_trial(tmp_path)
    synced = []
    real_fsync = os.fsync

    def spy(fd):
        synced.append(fd)
        real_fsync(fd)

    monkeypatch.setattr(files.os, 'fsync', spy)
    trials.append('trial-1', 0, 0, 1.0 * MM)
    assert len(synced) == 1  # the appended line, before append() returns
    atomic_write_text(tmp_path / 'x.txt', 'x')
    assert len(synced) == 3  # the temp file, then the directory after the rename


def test_truncated_last_line_is_ignored_and_the_next_append_is_clean(tmp_path):
    trials = _new_trial(tmp_path)
    _fill(trials, cycles=1)
    with open(_csv(tmp_path), 'ab') as f:
        f.write(b'1,0,P1,0.00101,0.0,,0.0010')  # crash mid-write: no newline
    restarted = TrialStore(tmp_path)
    data = restarted.load('trial-1')
    assert data.resume == (1, 0)
    assert np.isnan(data.distances[0, 1])
    assert any('truncated last line' in w for w in restarted.warnings)
    restarted.append('trial-1', 1, 0, 1.01 * MM, stamp_ns=9)
    again = TrialStore(tmp_path)
    data = again.load('trial-1')
    assert data.distances[0, 1] == pytest.approx(1.01 * MM)
    assert data.resume == (1, 1)
    assert any('ignored line' in w for w in again.warnings)  # the old fragment


def test_bad_middle_line_leaves_a_hole_and_cycle_out_of_the_statistics(tmp_path):
    _fill(_new_trial(tmp_path), cycles=3)
    path = _csv(tmp_path)
    lines = path.read_text().split('\n')
    lines[5] = lines[5].replace('P2', 'P9')  # file line 6: cycle 1, point 1
    path.write_text('\n'.join(lines))
    store = TrialStore(tmp_path)
    data = store.load('trial-1')
    assert data.missing == ((1, 1),)
    assert data.resume == (3, 0)
    assert point_statistics(data.distances).cycles == 2
    assert any(":6: ignored line, point name 'P9'" in w for w in store.warnings)


def test_redone_measurement_supersedes_the_earlier_one(tmp_path):
    trials = _new_trial(tmp_path)
    _fill(trials, cycles=1, extra_points=2)
    trials.append('trial-1', 1, 0, 2.0 * MM, stamp_ns=50)  # partial cycle redone
    assert TrialStore(tmp_path).load('trial-1').distances[0, 1] == 2.0 * MM


def test_status_and_listing_survive_restart(tmp_path):
    trials = _new_trial(tmp_path, 'trial-1', created=100)
    _new_trial(tmp_path, 'trial-2', created=200)
    (tmp_path / 'trials' / 'trial-3').mkdir()  # crash inside create()
    trials.set_status('trial-1', 'done', stamp_ns=300)
    with pytest.raises(ValueError, match='done'):
        trials.append('trial-1', 0, 0, 1.0 * MM)
    restarted = TrialStore(tmp_path)
    listed = restarted.list_trials()
    assert [(m['id'], m['status']) for m in listed] == [('trial-2', 'running'),
                                                         ('trial-1', 'done')]
    assert listed[1]['updated_ns'] == 300
    assert any('trial-3' in w for w in restarted.warnings)
    assert restarted.load('trial-3') is None
    restarted.set_status('trial-1', 'running', stamp_ns=400)
    restarted.append('trial-1', 0, 0, 1.0 * MM)


@pytest.mark.parametrize('cycle, point, raw', [(4, 0, 1e-3), (0, 3, 1e-3), (-1, 0, 1e-3),
                                               (0, 0, math.nan)])
def test_append_refuses_bad_measurements(tmp_path, cycle, point, raw):
    trials = _new_trial(tmp_path)
    with pytest.raises(ValueError):
        trials.append('trial-1', cycle, point, raw)
    assert _csv(tmp_path).read_text() == CSV_HEADER + '\n'


def test_create_refuses_bad_metadata(tmp_path):
    trials = TrialStore(tmp_path)
    kwargs = {'method': 'five_points', 'axis': 'z', 'layout': 'close', 'cycles_total': 4}
    with pytest.raises(ValueError):
        trials.create('t', point_names=['P1', 'P1'], **kwargs)
    with pytest.raises(ValueError):
        trials.create('t', point_names=['P1'], **{**kwargs, 'axis': 'w'})
    with pytest.raises(ValueError):
        trials.create('a/b', point_names=['P1'], **kwargs)
    assert trials.list_trials() == []


# -- the active calibration: chosen or newest, retired ones kept but never active --------------

def _three(root: Path) -> CalibrationStore:
    store = CalibrationStore(root)
    for record_id, stamp in [('cal-a', 1_000), ('cal-b', 2_000), ('cal-c', 3_000)]:
        store.save(_record(record_id, stamp))
    return store


def _active_id(store: CalibrationStore):
    active = store.active()
    return None if active is None else active['id']


def test_active_is_the_newest_until_one_is_chosen_and_the_choice_survives_restart(tmp_path):
    store = _three(tmp_path)
    assert _active_id(store) == 'cal-c'
    assert not (tmp_path / 'calibrations' / 'active.json').exists()   # nothing chosen yet
    store.activate('cal-a')
    assert _active_id(store) == 'cal-a'
    restarted = CalibrationStore(tmp_path)
    assert _active_id(restarted) == 'cal-a'
    assert [r['id'] for r in restarted.history()] == ['cal-c', 'cal-b', 'cal-a']
    assert restarted.warnings == []              # active.json is not read as a record
    restarted.activate('')                       # back to the default
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-c'


def test_a_new_record_activated_replaces_the_choice(tmp_path):
    store = _three(tmp_path)
    store.activate('cal-a')
    store.save(_record('cal-d', 4_000))
    assert _active_id(store) == 'cal-a'          # saving alone changes nothing
    store.activate('cal-d')
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-d'
    # a record that is not the newest (a sim clock started over) stays active when activated
    store.save(_record('cal-e', 500))
    store.activate('cal-e')
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-e'


def test_retired_stays_in_the_history_and_is_never_the_default(tmp_path):
    store = _three(tmp_path)
    store.retire('cal-c')
    assert _active_id(store) == 'cal-b'
    store.activate('cal-a')
    store.retire('cal-a')                        # the chosen one: the newest non-retired again
    restarted = CalibrationStore(tmp_path)
    assert _active_id(restarted) == 'cal-b'
    assert restarted.retired() == {'cal-a', 'cal-c'}
    assert [r['id'] for r in restarted.history()] == ['cal-c', 'cal-b', 'cal-a']
    assert restarted.get('cal-c') is not None
    restarted.retire('cal-b')
    assert restarted.active() is None
    restarted.activate('cal-c')                  # activating un-retires
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-c'
    assert CalibrationStore(tmp_path).retired() == {'cal-a', 'cal-b'}


def test_choosing_an_unknown_or_malformed_id_changes_nothing(tmp_path):
    store = _three(tmp_path)
    store.activate('cal-a')
    with pytest.raises(KeyError):
        store.activate('cal-z')
    with pytest.raises(KeyError):
        store.retire('cal-z')
    with pytest.raises(ValueError):
        store.activate('../cal-a')
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-a'
    assert CalibrationStore(tmp_path).retired() == frozenset()


def test_failed_choice_write_keeps_the_old_choice(tmp_path, monkeypatch):
    store = _three(tmp_path)
    store.activate('cal-a')

    def crash(src, dst):
        raise OSError('disk gone')

    monkeypatch.setattr(files.os, 'replace', crash)
    with pytest.raises(OSError, match='disk gone'):
        store.retire('cal-a')
    assert _active_id(store) == 'cal-a' and store.retired() == frozenset()
    monkeypatch.undo()
    assert _active_id(CalibrationStore(tmp_path)) == 'cal-a'


@pytest.mark.parametrize('text', ['{"active_id": "cal-a", "retired": [1]}\n',
                                  '{"active_id": "../x"}\n', '["cal-a"]\n', '{"active_id": '])
def test_a_bad_active_file_is_ignored_with_a_warning(tmp_path, text):
    store = _three(tmp_path)
    (tmp_path / 'calibrations' / 'active.json').write_text(text)
    restarted = CalibrationStore(tmp_path)
    assert _active_id(restarted) == 'cal-c' and restarted.retired() == frozenset()
    assert len(restarted.warnings) == 1 and 'active.json' in restarted.warnings[0]
    assert [r['id'] for r in restarted.history()] == ['cal-c', 'cal-b', 'cal-a']


def test_the_id_of_the_active_file_is_reserved(tmp_path):
    with pytest.raises(ValueError, match='reserved'):
        CalibrationStore(tmp_path).save(_record('active', 1))
