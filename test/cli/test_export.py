"""`cobot-calib export`: a stored user frame as controller syntax (no ROS needed)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cobot_calib_ros.cli.main import main
from cobot_calib_ros.core.vendor_frames import from_values

STORE = Path(__file__).resolve().parents[1] / 'data' / 'store-5252a67'
RIGID = '20261125T150121.300898935Z-rigid'


def _T_base_user(record_id: str) -> np.ndarray:
    record = json.loads((STORE / 'calibrations' / f'{record_id}.json').read_text())
    return np.array(record['result']['T_base_user'])


@pytest.mark.parametrize('fmt', ['kuka', 'abb', 'fanuc', 'ur', 'yaskawa'])
def test_export_json_values_give_back_the_stored_frame(fmt, capsys):
    assert main(['export', RIGID, '--format', fmt, '--json', '--data-dir', str(STORE)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['id'] == RIGID and out['format'] == fmt
    T = from_values(list(out['values'].values()), fmt)
    assert np.allclose(T, _T_base_user(RIGID), rtol=0, atol=1e-12)


def test_export_prints_paste_ready_krl_of_the_active_frame(capsys):
    assert main(['export', 'active', '--format', 'kuka', '--index', '4',
                 '--data-dir', str(STORE)]) == 0
    lines = capsys.readouterr().out.splitlines()
    newest = RIGID              # the newest stamp_ns: active by default
    assert lines[0] == f'; user frame in the robot base: cobot_calib {newest} (rigid)'
    assert lines[1].startswith('BASE_DATA[4]={X ') and lines[1].endswith('}')
    x_mm = float(lines[1].split('X ')[1].split(',')[0])
    assert x_mm == pytest.approx(_T_base_user(newest)[0, 3] * 1e3, abs=1e-4)


def test_export_of_an_unknown_id_says_where_it_looked(capsys):
    assert main(['export', 'no-such-id', '--format', 'ur', '--data-dir', str(STORE)]) == 1
    assert "no user-frame calibration 'no-such-id'" in capsys.readouterr().err
    assert main(['export', '../etc', '--format', 'ur', '--data-dir', str(STORE)]) == 2
