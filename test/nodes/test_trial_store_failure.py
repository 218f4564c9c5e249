"""A trial store that cannot be written is answered STORAGE_FAILED, not INVALID_INPUT (issue 39
item 1: disk and permission errors have their own cause); in-process, no node spun."""
from __future__ import annotations

from cobot_calib_msgs.action import RunTrial
import pytest

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.nodes.repeatability_trial import store_failure
from cobot_calib_ros.ros import results
from cobot_calib_ros.store.trials import TrialStore


def test_a_store_that_cannot_be_written_is_a_storage_failure(tmp_path):
    blocked = tmp_path / 'data'
    blocked.write_text('a file where the data folder should be')   # fails as root too
    with pytest.raises(OSError) as raised:
        TrialStore(blocked).create('t-1', method='rigid', axis='z', layout='close',
                                   point_names=['P1', 'P2', 'P3'], cycles_total=3)
    failure = store_failure(blocked / 'trials', raised.value)
    assert failure.code == ErrorCode.STORAGE_FAILED
    assert 'resume the trial' in failure.message and str(blocked) in failure.message
    answer = results.fill(RunTrial.Result(), 'RunTrial', failure)
    assert answer.error_code == RunTrial.Result.STORAGE_FAILED
