"""Intrinsics records (store.records.IntrinsicsRecord): one active per cell and camera, only
when the gate passes, in the folder store, SQLite and PostgreSQL alike."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.intrinsics import Coverage, IntrinsicsFit
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.records import active_intrinsics, IntrinsicsRecord
from cobot_calib_ros.store.repository import FolderRepository

_plants = itertools.count()
CELL = ResultsCell('ur10e_close', 'ur10e')


@pytest.fixture(params=['folder', 'sqlite', 'postgresql'])
def repo(request, tmp_path):
    if request.param == 'folder':
        (tmp_path / 'calibrations').mkdir()
        return FolderRepository(tmp_path, CELL)
    url = (f'sqlite:///{tmp_path / "results.sqlite"}' if request.param == 'sqlite'
           else request.getfixturevalue('postgres_url'))
    return store.open(tmp_path, url, ResultsCell(f'p{next(_plants)}_{id(request)}', 'ur10e'))


def _fit(fx: float, gate: str = '', heldout: float = 0.031) -> IntrinsicsFit:
    camera = CameraModel(752, 480, [[fx, 0, 380.0], [0, fx, 237.0], [0, 0, 1]],
                         [-0.15, 0.12, 0.0003, -0.0004, -0.05], 'plumb_bob', 'wrist')
    coverage = Coverage(np.ones((4, 4), bool), 1.0, (), (), 40.0)
    return IntrinsicsFit(camera, 0.029, {'v0': 0.028, 'v1': 0.03}, (), heldout, coverage, 2,
                         {}, gate)


def test_active_per_camera_only_when_the_gate_passes(repo):
    good = IntrinsicsRecord.from_fit(_fit(628.0), camera='wrist_camera_optical',
                                     source='bag', board='charuco:...', views=['v0', 'v1'],
                                     wall_ns=1_000)
    bad = IntrinsicsRecord.from_fit(_fit(640.0, gate='held-out RMS too high'),
                                    camera='wrist_camera_optical', source='bag',
                                    board='charuco:...', views=['v0', 'v1'], wall_ns=2_000)
    other = IntrinsicsRecord.from_fit(_fit(900.0, heldout=float('nan')), camera='scene_camera',
                                      source='folder', board='charuco:...', views=['v0', 'v1'],
                                      wall_ns=3_000)
    assert repo.intrinsics.save_and_activate(good)
    outcome = repo.intrinsics.save_and_activate(bad)
    assert not outcome and 'held-out RMS too high' in outcome.reason
    assert repo.intrinsics.save_and_activate(other)
    camera = active_intrinsics(repo, 'wrist_camera_optical')
    assert camera.K[0, 0] == 628.0 and camera.name == 'wrist_camera_optical'
    np.testing.assert_array_equal(camera.D, [-0.15, 0.12, 0.0003, -0.0004, -0.05])
    assert (camera.width, camera.height, camera.distortion_model) == (752, 480, 'plumb_bob')
    assert active_intrinsics(repo, 'scene_camera').K[0, 0] == 900.0
    assert active_intrinsics(repo, 'no_such_camera') is None
    stored = repo.intrinsics.get(other.id)
    assert stored['result']['heldout_rms_px'] is None and stored['cell'] == repo.cell.name
    assert IntrinsicsRecord.from_dict(stored).result.views_used == 2
