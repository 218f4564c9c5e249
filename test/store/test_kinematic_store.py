"""Kinematic calibrations of many robots in one data dir: 'latest' is per robot (issue 16.1)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobot_calib_ros.core.kinematics import fk, model_by_name
from cobot_calib_ros.core.rig import model_chain
from cobot_calib_ros.store.rigs import kinematics_of
from cobot_calib_ros.store.kinematics import KinematicStore, LATEST, NOMINAL

from test_kinematics_writeback import record_of


def _kinematic_record(robot: str, record_id: str, stamp_ns: int, offset: float = 0.0) -> dict:
    """A stored kinematic calibration of ``robot``: its nominal parameters + ``offset`` [m/rad]."""
    model = model_by_name(robot)
    return {'id': record_id, 'stamp_ns': stamp_ns, 'method': 'relative-lm', 'robot': robot,
            'inputs': {'source': 'test'},
            'result': {'parameter_names': list(model.parameter_names),
                       'params': (np.asarray(model.nominal) + offset).tolist(),
                       'p_flange_tool': [0.0, 0.0, 0.0]}}


def test_an_iiwa7_calibration_leaves_the_sawyer_on_nominal(tmp_path):
    """On 5252a67, 'latest' was the newest record of any robot: after `identify --robot iiwa7`
    every Sawyer request failed ("... is for robot 'iiwa7', not 'sawyer'")."""
    KinematicStore(tmp_path).save(_kinematic_record('iiwa7', 'iiwa-1', 1_000))
    store = KinematicStore(tmp_path)                    # as a node reads it: fresh
    assert store.resolve(LATEST, 'sawyer') is None      # nominal: the Sawyer has none
    sawyer = model_by_name('sawyer')
    q = np.zeros(len(sawyer.lower))
    np.testing.assert_array_equal(fk(model_chain(kinematics_of(store.resolve(LATEST, 'sawyer')), sawyer, None), q),
                                  fk(sawyer.chain(), q))
    assert store.resolve(LATEST, 'iiwa7')['id'] == 'iiwa-1'
    with pytest.raises(ValueError, match="for robot 'iiwa7', not 'sawyer'"):
        model_chain(kinematics_of(store.resolve('iiwa-1', 'sawyer')), sawyer, np.eye(4))   # named: refused


def test_the_sawyer_uses_its_own_latest_and_activation_is_per_robot(tmp_path):
    store = KinematicStore(tmp_path)
    store.save(_kinematic_record('sawyer', 'sawyer-1', 1_000, offset=1e-4))
    store.save(_kinematic_record('sawyer', 'sawyer-2', 2_000, offset=2e-4))
    store.save(_kinematic_record('iiwa7', 'iiwa-1', 3_000))     # the newest of all
    fresh = KinematicStore(tmp_path)
    assert fresh.resolve(LATEST, 'sawyer')['id'] == 'sawyer-2'
    assert fresh.resolve(NOMINAL, 'sawyer') is None
    sawyer = model_by_name('sawyer')
    q = np.zeros(len(sawyer.lower))
    np.testing.assert_array_equal(fk(model_chain(kinematics_of(fresh.resolve(LATEST, 'sawyer')), sawyer, None), q),
                                  fk(sawyer.chain(np.asarray(sawyer.nominal) + 2e-4), q))
    fresh.activate('sawyer-1')                                  # the Sawyer's choice ...
    fresh.activate('iiwa-1')                                    # ... survives the iiwa's
    again = KinematicStore(tmp_path)
    assert again.resolve(LATEST, 'sawyer')['id'] == 'sawyer-1'
    assert again.resolve(LATEST, 'iiwa7')['id'] == 'iiwa-1'
    again.retire('iiwa-1')
    assert KinematicStore(tmp_path).resolve(LATEST, 'iiwa7') is None
    assert KinematicStore(tmp_path).resolve(LATEST, 'sawyer')['id'] == 'sawyer-1'


def test_an_active_json_written_before_scopes_still_reads(tmp_path):
    """5252a67 wrote one ``active_id`` for all robots: it counts for its own record's robot."""
    store = KinematicStore(tmp_path)
    store.save(_kinematic_record('sawyer', 'sawyer-1', 1_000))
    store.save(_kinematic_record('sawyer', 'sawyer-2', 2_000))
    store.save(_kinematic_record('iiwa7', 'iiwa-1', 3_000))
    (tmp_path / 'kinematics' / 'active.json').write_text(
        json.dumps({'active_id': 'sawyer-1', 'retired': []}) + '\n')
    fresh = KinematicStore(tmp_path)
    assert fresh.resolve(LATEST, 'sawyer')['id'] == 'sawyer-1'
    assert fresh.resolve(LATEST, 'iiwa7')['id'] == 'iiwa-1'
    assert fresh.warnings == []


def test_a_record_is_seen_only_with_its_urdf_and_a_refused_one_writes_nothing(tmp_path):
    """A reader that sees a new kinematic record finds its URDF and YAML (kinematic_identifier's
    robot_description check once found the record first: 'No such file'); a record of another
    robot is refused with no file left behind."""
    from cobot_calib_ros.core.errors import Refusal
    from cobot_calib_ros.store.cells import ResultsCell
    store = KinematicStore(tmp_path, cell=ResultsCell('cell_a', 'sawyer'))
    model = model_by_name('sawyer')
    typed = record_of(model, model.nominal, 'k-1')
    seen_with = []
    put = store._put

    def recording_put(plain):       # the moment the record becomes visible to readers
        seen_with.extend(sorted(p.name for p in store.directory.iterdir()))
        return put(plain)

    store._put = recording_put
    saved = store.save_record(typed, model)
    assert seen_with == ['k-1.urdf', 'k-1.yaml']
    assert KinematicStore(tmp_path, cell=ResultsCell('cell_a', 'sawyer')).active('sawyer')[
        'id'] == 'k-1' and saved.paths['urdf'].is_file()
    before = sorted(p.name for p in store.directory.iterdir())
    model = model_by_name('iiwa7')
    foreign = record_of(model, model.nominal, 'k-2')
    with pytest.raises(Refusal, match='made on the iiwa7; this is cell'):
        store.save_record(foreign, model)
    assert sorted(p.name for p in store.directory.iterdir()) == before
