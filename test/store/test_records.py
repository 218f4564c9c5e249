"""Typed records (store.records), one repository (store.open) and the activation gate.

Files written by 5252a67 (test/data/store-5252a67) must still load and round-trip unchanged;
the typed builders must write the keys those files have."""
from __future__ import annotations

import json
from pathlib import Path
import shutil

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core import user_frame
from cobot_calib_ros.store.records import (HandEyeRecord, KinematicRecord, Record, TrialSetup,
                                           UserFrameRecord)
from cobot_calib_ros.store.renamed import with_current_names

DATA = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67'
KINDS = {'calibrations': UserFrameRecord, 'hand_eye': HandEyeRecord,
         'kinematics': KinematicRecord}


def _stored(kind: str) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((DATA / kind).glob('*.json'))]


@pytest.fixture
def data_dir(tmp_path) -> Path:
    """A copy of the 5252a67 data dir (the tests write into it)."""
    shutil.copytree(DATA, tmp_path / 'data')
    return tmp_path / 'data'


@pytest.mark.parametrize('kind', sorted(KINDS))
def test_files_written_by_5252a67_load_and_round_trip_unchanged(kind):
    """Unchanged but for the keys renamed since (issue 39.3, store.renamed)."""
    stored = _stored(kind)
    assert stored
    for data in stored:
        record = KINDS[kind].from_dict(data)
        assert record.id == data['id'] and record.extra == {}
        assert record.to_dict() == with_current_names(data)


def test_a_kinematics_record_of_5252a67_gives_its_tool_position_as_p_flange_tool(data_dir):
    old = _stored('kinematics')[0]['result']['tool_xyz']     # legacy name
    assert len(old) == 3
    record = KinematicRecord.from_dict(_stored('kinematics')[0])
    assert record.result.p_flange_tool == old
    repo = store.open(data_dir)
    stored = repo.kinematics.get(_stored('kinematics')[0]['id'])
    assert stored['result']['p_flange_tool'] == old
    assert 'tool_xyz' not in stored['result']                  # legacy name


def test_the_user_frame_builder_writes_what_5252a67_wrote():
    """The same fit of the same points gives the same mapping as 5252a67's fit_record."""
    old = next(d for d in _stored('calibrations') if d['method'] == 'rigid')
    inputs = old['inputs']
    fit = user_frame.calibrate('rigid', inputs['points_user'], inputs['points_base'],
                               names=inputs['point_names'])
    surface = user_frame.fit_surface(np.array(inputs['points_user']),
                                     np.array(inputs['points_base']), fit.M,
                                     names=inputs['point_names'])
    new = UserFrameRecord.from_fit(fit, surface, inputs['point_names'],
                                   np.array(inputs['points_user']),
                                   np.array(inputs['points_base']),
                                   (old['base_frame'], old['user_frame']), old['stamp_ns'],
                                   old['kinematics']).to_dict()
    assert new['id'].endswith('-rigid')
    assert {**new, 'id': old['id']} == old
    typed = UserFrameRecord.from_dict(old)
    assert typed.surface_model().coefficients.tolist() == old['result']['surface']['coefficients']
    assert typed.result.rms == old['result']['rms']


def test_keys_a_reader_does_not_know_are_kept_and_missing_ones_are_named():
    data = {**_stored('hand_eye')[0], 'exposure_check': {'skew_s': 0.01}}
    record = HandEyeRecord.from_dict(data)
    assert record.extra == {'exposure_check': {'skew_s': 0.01}}
    assert record.to_dict() == data
    broken = {k: v for k, v in data.items() if k not in ('cell', 'result')}
    with pytest.raises(ValueError, match=r"HandEyeRecord: missing keys \['cell', 'result'\]"):
        HandEyeRecord.from_dict(broken)
    with pytest.raises(ValueError, match='expected a mapping'):
        Record.from_dict(['not', 'a', 'mapping'])


def test_gate_problem_and_hand_eye_are_written_only_when_set():
    typed = UserFrameRecord.from_dict(_stored('calibrations')[0])
    assert 'gate_problem' not in typed.to_dict()
    typed.gate_problem = 'residual 14.5 mm > 0.2 mm'
    assert typed.to_dict()['gate_problem'] == 'residual 14.5 mm > 0.2 mm'
    setup = TrialSetup(method='rigid', axis='z', cycles_total=2, point_names=('P1', 'P2'))
    assert setup.to_dict() == {'method': 'rigid', 'axis': 'z', 'cycles_total': 2,
                               'point_names': ['P1', 'P2']}


def test_one_repository_reads_every_kind_of_a_5252a67_data_dir(data_dir):
    repo = store.open(data_dir)
    newest = max(_stored('calibrations'), key=lambda d: d['stamp_ns'])
    assert repo.user_frames.active()['id'] == newest['id']
    assert repo.hand_eye.active()['id'] == _stored('hand_eye')[0]['id']
    iiwa = _stored('kinematics')[0]
    assert repo.kinematics.resolve('latest', 'iiwa7')['id'] == iiwa['id']
    assert repo.kinematics.resolve('latest', 'sawyer') is None
    trial = repo.trials.load('trial-1')
    assert trial.meta['method'] == 'rigid' and trial.distances[0, 0] == pytest.approx(0.0012)
    assert repo.collections.list_collections() == []
    assert repo.user_frames is repo.user_frames        # one store per kind and repository
    assert store.open(data_dir).user_frames is not repo.user_frames   # a fresh read


# -- the gate: a record that fails is kept, marked rejected, never active ---------------------

def _hand_eye(stamp_ns: int, record_id: str, gate_problem: str = '') -> HandEyeRecord:
    record = HandEyeRecord.from_dict(_stored('hand_eye')[0])
    record.id, record.stamp_ns, record.gate_problem = record_id, stamp_ns, gate_problem
    return record


def test_a_record_that_fails_its_gate_is_kept_but_never_active(data_dir):
    history = store.open(data_dir).hand_eye
    good = history.active()['id']
    why = 'residual 14.5 mm: beyond the 0.2 mm the views allow'
    activation = history.save_and_activate(_hand_eye(10**20, 'hand_eye-wrong', why))
    assert not activation and activation.record_id == 'hand_eye-wrong'
    assert why in activation.reason and 'rejected' in activation.reason
    assert history.active()['id'] == good                 # though it is the newest
    assert history.rejected() == {'hand_eye-wrong': why}
    assert [r['id'] for r in history.history()][0] == 'hand_eye-wrong'   # kept
    refused = history.activate('hand_eye-wrong')             # asked for by id: refused too
    assert not refused and why in refused.reason
    assert history.activate(None).record_id == good          # the default skips it
    fresh = store.open(data_dir).hand_eye                    # and after a restart
    assert fresh.active()['id'] == good and fresh.get('hand_eye-wrong')['gate_problem'] == why
    passing = fresh.save_and_activate(_hand_eye(10**20 + 1, 'hand_eye-right'))
    assert passing and passing.record_id == 'hand_eye-right' and passing.reason == ''
    assert store.open(data_dir).hand_eye.active()['id'] == 'hand_eye-right'


def test_a_gate_given_by_the_kind_as_a_callable(data_dir):
    """A history may take the criterion as a callable (record -> problem) instead."""
    from cobot_calib_ros.store.calibrations import CalibrationStore
    limit_mm = 0.2
    history = CalibrationStore(data_dir, 'hand_eye', gate=lambda r: (
        f'residual {r["result"]["residual_mm"]:.3f} mm > {limit_mm} mm'
        if r['result']['residual_mm'] > limit_mm else ''))
    wide = _hand_eye(10**20, 'hand_eye-wide')
    wide.result.residual_mm = 14.5
    activation = history.save_and_activate(wide)
    assert not activation and 'residual 14.500 mm > 0.2 mm' in activation.reason
    assert history.active()['id'] != 'hand_eye-wide'


def test_the_gate_is_per_robot_for_kinematics(data_dir):
    repo = store.open(data_dir)
    iiwa = KinematicRecord.from_dict(_stored('kinematics')[0])
    rejected = KinematicRecord.from_dict(iiwa.to_dict())
    rejected.id, rejected.stamp_ns = 'iiwa7-diverged', iiwa.stamp_ns + 1
    rejected.gate_problem = 'held-out max 3.2 mm > nominal 1.1 mm'
    assert not repo.kinematics.save_and_activate(rejected)
    assert repo.kinematics.resolve('latest', 'iiwa7')['id'] == iiwa.id
    assert repo.kinematics.resolve('latest', 'sawyer') is None
