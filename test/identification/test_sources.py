"""One loader and one api call (issue 28 item 5): loaders.sources recognises a measurement
CSV with its sidecar, a MUKCa folder, a bag and a collection folder, and
api.identification.identify_source identifies each through the one engine with the same
report shape; anything else gets one line naming what was looked for. A collection folder is
identified offline, without a suite, by the node's CalibrationJob: the bag's captures written
as a collection give the bag's parameters."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.api.identification import identify_source
from cobot_calib_ros.cli.main import main
from cobot_calib_ros.loaders import sources

ROOT = Path(__file__).resolve().parents[2]
UR10E = ROOT / 'test' / 'data' / 'figaroh-ur10e'
MUKCA = ROOT / 'test' / 'data' / 'mukca-kuka-iiwa14'
BAG = ROOT / 'bags' / 'iiwa_spheres'
CELL = 'iiwa7_close'
SHAPE = {'source', 'source_kind', 'robot', 'measurement', 'rows', 'verdict', 'converged',
         'identified', 'dropped', 'bounds'}


def collection_of_the_bag(root: Path) -> Path:
    """The bag's sphere captures as collect_sphere_data stores them (store.collections)."""
    from cobot_calib_ros.bags.sphere_captures import sphere_observations
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    from cobot_calib_ros.store.collections import CollectionStore
    cell = load_cell(cell_file(CELL))
    model = model_for(cell)
    data, _ = sphere_observations(BAG, cell, model)
    store = CollectionStore(root)
    plan = [{'q': q.tolist(), 'target': int(t)} for q, t in zip(data.q, data.sphere)]
    store.create('from_bag', source='spheres', robot=cell.robot,
                 joint_names=list(model.joint_names), targets=list(cell.spheres.names),
                 plan=plan, extra={'known_distances': [list(d) for d in
                                                       cell.spheres.known_distances()]})
    for index, (q, target) in enumerate(zip(data.q, data.sphere)):
        store.append('from_bag', index, int(target), q)
    store.set_status('from_bag', 'done')
    return store.directory / 'from_bag'


@pytest.fixture(scope='module')
def collection(tmp_path_factory) -> Path:
    return collection_of_the_bag(tmp_path_factory.mktemp('data'))


def test_the_four_sources_are_recognised(collection):
    assert sources.recognise(UR10E / 'calibration.csv') == sources.MEASUREMENT_FILE
    assert sources.recognise(MUKCA / 'kuka_14') == sources.MUKCA
    assert sources.recognise(BAG) == sources.BAG
    assert sources.recognise(collection) == sources.COLLECTION


def test_anything_else_is_named_with_what_was_looked_for(tmp_path):
    looked_for = ('looked for a measurement CSV with its sidecar (NAME.csv + NAME.yaml), a '
                  'MUKCa folder (<location>/hole_0.csv), a bag (metadata.yaml or *.mcap) or a '
                  'collection folder (collection.json, or collection.yaml of older versions)')
    (tmp_path / 'notes.txt').mkdir()
    with pytest.raises(ValueError) as e:
        identify_source(tmp_path / 'notes.txt', cell=CELL)
    assert str(e.value) == f'{tmp_path / "notes.txt"}: a folder that is none of the sources; ' \
        f'{looked_for}'
    with pytest.raises(ValueError) as e:
        identify_source(tmp_path / 'gone', cell=CELL)
    assert str(e.value) == f'{tmp_path / "gone"}: no such file or folder; {looked_for}'


def test_each_source_is_identified_by_the_one_call_with_the_one_report_shape(collection):
    file = identify_source(UR10E / 'calibration.csv', urdf=str(UR10E / 'robot.urdf'))
    mukca = identify_source(MUKCA / 'kuka_14')                  # iiwa14.urdf beside it
    bag = identify_source(BAG, cell=CELL)
    stored = identify_source(collection, cell=CELL)
    for report, kind, measurement, rows in (
            (file, sources.MEASUREMENT_FILE, 'pose', 23), (mukca, sources.MUKCA, 'spheres', 180),
            (bag, sources.BAG, 'spheres', 150), (stored, sources.COLLECTION, 'spheres', 150)):
        assert SHAPE <= set(report), kind
        assert (report['source_kind'], report['measurement'], report['rows']) == \
            (kind, measurement, rows)
        assert report['verdict'] == {'passed': True, 'problems': []} and report['converged']
        assert all(set(p) >= {'name', 'value', 'nominal', 'delta'} for p in report['identified'])
        json.dumps(report)                                      # JSON-ready
    # held out where the source has rows to hold out: better than nominal and no worse than
    # the independent implementations on the same rows, FIGAROH's 4.33 mm and MUKCa's 0.233 mm
    # (within 2 % for their fold partitions: test/test_real_data.py)
    for report, key, anchor in ((file, 'rmse_mm', 4.33), (mukca, 'mean_mm', 0.233)):
        held_out = report['held_out']
        assert held_out['calibrated'][key] < held_out['nominal'][key]
        assert held_out['calibrated'][key] <= anchor * 1.02
    assert mukca['validation'] == {'leave_out': 'location',
                                   'groups': ['front', 'left_back', 'raised_left']}
    # the collection holds the bag's poses: the same job, the same parameters, bit for bit
    assert stored['collection'] == 'from_bag' and stored['calibration_id'] == ''
    assert [p['name'] for p in stored['identified']] == [p['name'] for p in bag['identified']]
    np.testing.assert_array_equal([p['value'] for p in stored['identified']],
                                  [p['value'] for p in bag['identified']])
    assert stored['dropped'] == bag['dropped'] and len(bag['dropped']) == 6
    expected = json.loads((BAG / 'expected.json').read_text())
    live = {p['name']: p['value'] for p in expected['identified']}
    # the live session was recorded before the prior around nominal (issue 37), which moves
    # these well-determined parameters by 1.0e-7 (m or rad); bit for bit before it
    assert max(abs(p['value'] - live[p['name']]) for p in stored['identified']) <= 2e-7


def test_options_a_source_does_not_take_are_named(collection):
    with pytest.raises(ValueError, match=r'--urdf, --folds apply to a measurement file or a '
                                         r'MUKCa folder, not a collection'):
        identify_source(collection, cell=CELL, urdf='robot.urdf', folds=3)
    with pytest.raises(ValueError, match=r'--max-configs apply to a bag or a collection folder, '
                                         r'not a MUKCa folder'):
        identify_source(MUKCA / 'kuka_14', max_configs=10)


def test_a_collection_of_another_robot_is_refused_in_one_line(collection, capsys):
    assert main(['identify', '--source', str(collection), '--robot', 'sawyer']) == 1
    err = capsys.readouterr().err
    assert err == f'identify: {collection}: collection from_bag is of a iiwa7, this cell is a ' \
        'sawyer\n'


def test_the_cli_identifies_a_collection_without_a_suite_and_stores_it(tmp_path, monkeypatch,
                                                                       capsys):
    """`identify --source COLLECTION` (no --attach): offline, stored and made active in the
    data dir as the node would; --dry-run stores nothing."""
    monkeypatch.setenv('COBOT_CALIB_DATA', str(tmp_path))
    folder = collection_of_the_bag(tmp_path)
    assert main(['identify', '--source', str(folder), '--dry-run', '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert report['source_kind'] == 'collection' and report['calibration_id'] == ''
    assert not (tmp_path / 'kinematics').exists()
    assert main(['identify', '--source', str(folder)]) == 0
    out = capsys.readouterr().out
    assert 'gate: passed' in out and 'converged: yes' in out and 'stored and active: ' in out
    from cobot_calib_ros import store
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    from cobot_calib_ros.store.cells import ResultsCell
    kinematics = store.open(tmp_path, cell=ResultsCell.of(load_cell(cell_file(CELL)))).kinematics
    active = kinematics.resolve('latest', 'iiwa7')
    assert active is not None and f'stored and active: {active["id"]}' in out
    assert active['inputs']['source'] == 'from_bag'
