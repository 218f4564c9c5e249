"""Kinematic data collections and kinematic calibrations on disk (store.collections,
store.kinematics): atomic, resumable, readable after a crash."""
import math

import numpy as np
import pytest

from cobot_calib_ros.core.kinematics import model_by_name
from cobot_calib_ros.store.collections import CollectionStore
from cobot_calib_ros.core.rig import model_chain
from cobot_calib_ros.store.rigs import kinematics_of
from cobot_calib_ros.store.kinematics import KinematicStore

PLAN = [{'q': [0.1 * i] * 7, 'target': i % 3} for i in range(6)]


def _new(tmp_path, plan=PLAN):
    store = CollectionStore(tmp_path)
    store.create('c1', source='spheres', robot='iiwa7', joint_names=[f'j{i}' for i in range(7)],
                 targets=['S1', 'S2', 'S3'], plan=plan,
                 extra={'known_distances': [[0, 1, 0.3]]})
    return store


def test_rows_come_back_in_plan_order_with_skips_and_resume_point(tmp_path):
    store = _new(tmp_path)
    q = np.linspace(-1.0, 1.0, 7)
    store.append('c1', 0, 0, q, sample_count=50, std_max=2e-6)
    store.append('c1', 1, 1, None, note='unreachable, IK failed')
    store.append('c1', 3, 0, q + 1e-3)
    data = CollectionStore(tmp_path).load('c1')      # a fresh store: read from disk
    assert data.index.tolist() == [0, 3] and data.target.tolist() == [0, 0]
    np.testing.assert_array_equal(data.q[0], q)       # repr round trip: bit-exact
    assert np.isnan(data.p).all()
    assert data.skipped == {1: 'unreachable; IK failed'}
    assert data.next_index == 2
    assert data.meta['known_distances'] == [[0, 1, 0.3]]


def test_a_collection_of_an_older_version_in_yaml_is_read_resumed_and_written_as_json(tmp_path):
    """Collections before session 23 kept their metadata in collection.yaml (a planned iiwa 7
    collection's 5.8 MB took 4.5 s to read with libyaml, JSON 0.07 s): still read, and the next
    write replaces it with collection.json."""
    import json
    from cobot_calib_ros.store.files import dump_yaml
    store = _new(tmp_path)
    store.append('c1', 0, 0, np.zeros(7))
    folder = store.directory / 'c1'
    meta = json.loads((folder / 'collection.json').read_text())
    assert meta['plan'] == PLAN and meta['known_distances'] == [[0, 1, 0.3]]
    (folder / 'collection.yaml').write_text(dump_yaml(meta, sort_keys=False))
    (folder / 'collection.json').unlink()
    old = CollectionStore(tmp_path)
    data = old.load('c1')
    assert data.meta['plan'] == PLAN and data.next_index == 1
    old.set_status('c1', 'done')
    assert sorted(p.name for p in folder.iterdir()) == ['collection.json', 'rows.csv']
    assert CollectionStore(tmp_path).meta('c1')['status'] == 'done'


def test_a_row_cut_by_a_crash_is_dropped_and_reported(tmp_path):
    store = _new(tmp_path)
    store.append('c1', 0, 0, np.zeros(7))
    path = store.directory / 'c1' / 'rows.csv'
    with open(path, 'a') as f:
        f.write('1,1,ok,50,1e-06,0.1,0.2')             # no newline: the write in flight
    fresh = CollectionStore(tmp_path)
    data = fresh.load('c1')
    assert data.index.tolist() == [0] and data.next_index == 1
    assert any('truncated' in w for w in fresh.warnings)
    fresh.append('c1', 1, 1, np.ones(7))               # the next append ends the cut line
    assert CollectionStore(tmp_path).load('c1').index.tolist() == [0, 1]


def test_status_and_listing_newest_first(tmp_path):
    store = _new(tmp_path)
    store.create('c2', source='laser_tracker', robot='iiwa7', joint_names=['a'] * 7,
                 targets=[], plan=[{'q': [0.0] * 7, 'target': -1}])
    store.set_status('c1', 'done')
    assert [m['id'] for m in CollectionStore(tmp_path).list_collections()] == ['c2', 'c1']
    assert CollectionStore(tmp_path).meta('c1')['status'] == 'done'


@pytest.mark.parametrize('q', [np.full(7, math.nan), np.zeros(6)])
def test_bad_rows_and_plans_are_refused(tmp_path, q):
    store = _new(tmp_path)
    with pytest.raises(ValueError, match='7 finite joint positions'):
        store.append('c1', 0, 0, q)
    with pytest.raises(ValueError, match='plan step'):
        store.create('c3', source='spheres', robot='iiwa7', joint_names=['a'] * 7, targets=[],
                     plan=[{'q': [0.0] * 6, 'target': 0}])
    with pytest.raises(ValueError, match='source'):
        store.create('c4', source='camera', robot='iiwa7', joint_names=['a'] * 7, targets=[],
                     plan=PLAN)


def test_kinematic_records_resolve_and_build_their_chain(tmp_path):
    model = model_by_name('iiwa7')
    params = model.nominal.copy()
    params[model.parameter_names.index('d_3')] += 5e-4
    store = KinematicStore(tmp_path)
    record = {'id': 'k1', 'stamp_ns': 1, 'method': 'relative-lm', 'robot': 'iiwa7',
              'inputs': {}, 'result': {'parameter_names': list(model.parameter_names),
                                       'params': params}}
    store.save(record)
    fresh = KinematicStore(tmp_path)
    assert fresh.resolve('nominal', 'iiwa7') is None
    assert fresh.resolve('latest', 'iiwa7')['id'] == 'k1' == fresh.resolve('k1', 'iiwa7')['id']
    with pytest.raises(KeyError, match='no kinematic calibration'):
        fresh.resolve('k2', 'iiwa7')
    chain = model_chain(kinematics_of(fresh.resolve('latest', 'iiwa7')), model, np.eye(4))
    np.testing.assert_allclose(chain.placements, model.chain(params).placements, atol=0)
    with pytest.raises(ValueError, match="not 'sawyer'"):
        model_chain(kinematics_of(fresh.get('k1')), model_by_name('sawyer'), np.eye(4))
    assert KinematicStore(tmp_path / 'empty').resolve('latest', 'iiwa7') is None


def test_why_a_folder_record_is_unreadable_is_this_calls_answer(tmp_path):
    """Trials and collections share one folder store (store.folders); why a record cannot be
    read is the answer of one call, not the last line of a shared ``warnings`` list."""
    from cobot_calib_ros.store.trials import TrialStore
    collections = _new(tmp_path)
    trials = TrialStore(tmp_path)
    trials.create('t1', method='rigid', axis='z', layout='close', point_names=['P1'],
                  cycles_total=2)
    assert collections.meta_problem('c1') == trials.meta_problem('t1') == ''
    (tmp_path / 'kinematic_data' / 'c1' / 'collection.json').write_text('["a list"]\n')
    (tmp_path / 'trials' / 't1' / 'trial.yaml').write_text('id: t1\n')
    fresh_collections, fresh_trials = CollectionStore(tmp_path), TrialStore(tmp_path)
    assert fresh_collections.meta_problem('c1').endswith('collection.json: skipped, not a mapping')
    assert 'missing keys' in fresh_trials.meta_problem('t1')
    assert fresh_trials.meta_problem('t9').endswith('no trial.yaml (missing or aborted create)')
    assert fresh_collections.warnings == fresh_trials.warnings == []   # asked, not logged
    with pytest.raises(ValueError, match="collection 'c1' is missing or unreadable: .*mapping"):
        fresh_collections.meta('c1')
    assert fresh_collections.load('c1') is None and fresh_trials.list_trials() == []
    assert len(fresh_collections.warnings) == len(fresh_trials.warnings) == 1


def test_update_adds_metadata_durably_but_not_the_fixed_keys(tmp_path):
    """Issue 20: a planned collection's planning state is written at the end of each goal."""
    store = _new(tmp_path)
    store.update('c1', planning={'state': {'chosen': [3, 1], 'stop': 'max_poses: 2 poses'}})
    meta = CollectionStore(tmp_path).load('c1').meta       # a fresh store: read from disk
    assert meta['planning']['state'] == {'chosen': [3, 1], 'stop': 'max_poses: 2 poses'}
    assert meta['status'] == 'running' and meta['plan'] == PLAN
    with pytest.raises(ValueError, match=r"update cannot change \['status'\]"):
        store.update('c1', status='done')
