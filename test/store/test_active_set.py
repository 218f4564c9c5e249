"""store.rigs.active_set: a cell's active results as core.rig's typed records, and which of
them are stale (core.provenance) with the size of the change at the result (issue 36)."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core import rig
from cobot_calib_ros.core.frames import from_xyz_rpy
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import active_set

CELL = load_cell(cell_file('sawyer_close'))
MODEL = model_for(CELL)
PARAMS = MODEL.nominal + np.random.default_rng(7).normal(0.0, 3e-4, MODEL.nominal.size)
JOINTS = CELL.home + np.random.default_rng(8).normal(0.0, 0.3, (5, len(CELL.home)))


def _kinematics(record_id: str) -> dict:
    return {'id': record_id, 'stamp_ns': 1, 'method': 'test', 'robot': MODEL.name,
            'inputs': {}, 'measured_through': {},
            'result': {'parameter_names': list(MODEL.parameter_names),
                       'params': PARAMS.tolist()}}


def _tcp(record_id: str, through: dict | None) -> dict:
    record = {'id': record_id, 'stamp_ns': 2, 'method': 'tcp-5-point', 'tool': CELL.tool_frame,
              'inputs': {'joints': JOINTS.tolist()},
              'result': {'T_flange_tool': np.array(CELL.T_flange_tool).tolist(),
                         'orientation_method': 'none'}}
    return record if through is None else {**record, 'measured_through': through}


@pytest.fixture
def repo(tmp_path):
    return store.open(tmp_path, cell=ResultsCell.of(CELL))


def test_the_active_set_holds_each_kind_as_a_typed_record(repo):
    assert active_set(repo, CELL) == rig.ActiveSet()        # nothing stored: all nominal
    repo.kinematics.save_and_activate(_kinematics('k1'))
    repo.tcp.save_and_activate(_tcp('t1', {'kinematics': 'k1'}))
    X = from_xyz_rpy([0.05, 0.0, 0.02], [0.0, 0.0, 1.0])
    repo.hand_eye.save_and_activate({
        'id': 'h1', 'stamp_ns': 3, 'method': 'test', 'cell': CELL.name, 'inputs': {},
        'measured_through': {'kinematics': 'k1', 'intrinsics': 'nominal'},
        'result': {'T_flange_optical': X.tolist()}})
    active = active_set(repo, CELL)
    assert isinstance(active.kinematics, rig.Kinematics) and active.kinematics.id == 'k1'
    np.testing.assert_array_equal(active.kinematics.params, PARAMS)
    assert isinstance(active.tcp, rig.Tcp) and active.tcp_label == 't1'
    assert not active.tcp.orientation_measured and active.tcp.tool == CELL.tool_frame
    np.testing.assert_array_equal(active.hand_eye.T_flange_optical, X)
    assert (active.label('intrinsics'), active.label('user_frame')) == ('nominal', 'nominal')
    assert active.stale == ()      # each measured through what is in use
    assert active_set(repo, CELL, 'nominal').kinematics is None
    with pytest.raises(ValueError, match="no kinematic calibration 'k9'"):
        active_set(repo, CELL, 'k9')


def test_a_tcp_measured_through_nominal_kinematics_is_stale_once_a_calibration_is_active(repo):
    """The size is the largest move of the flange between the two kinematics at the TCP's own
    touches (its record's joints)."""
    repo.tcp.save_and_activate(_tcp('t1', {'kinematics': 'nominal'}))
    assert active_set(repo, CELL).stale == ()
    repo.kinematics.save_and_activate(_kinematics('k1'))
    (stale,) = active_set(repo, CELL).stale
    moved = np.linalg.norm(fk(MODEL.chain(PARAMS), JOINTS)[:, :3, 3]
                           - fk(MODEL.chain(), JOINTS)[:, :3, 3], axis=1).max()
    assert (stale.kind, stale.id, stale.through, stale.was, stale.now) == (
        'tcp', 't1', 'kinematics', 'nominal', 'k1')
    assert stale.change_mm == pytest.approx(moved * 1e3, rel=1e-12) and moved > 1e-4
    assert stale.line() == (f'TCP t1 was measured with kinematics nominal; the active '
                            f'kinematics k1 is {moved * 1e3:.3f} mm away at the flange over its '
                            '5 poses: calibrate the TCP again, or keep it')
    assert active_set(repo, CELL, 'nominal').stale == ()    # used with what it was made with


def test_a_record_without_provenance_is_never_stale(repo):
    repo.tcp.save_and_activate(_tcp('t0', None))            # written before measured_through
    repo.kinematics.save_and_activate(_kinematics('k1'))
    active = active_set(repo, CELL)
    assert active.tcp.measured_through == {} and active.stale == ()
