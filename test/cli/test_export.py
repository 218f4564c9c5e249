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


@pytest.mark.parametrize('fmt, index', [('fanuc', '0'), ('fanuc', '-1'), ('fanuc', '10'),
                                        ('kuka', '33'), ('kuka', '99'), ('yaskawa', '64'),
                                        ('abb', '2'), ('ur', '1')])
def test_export_refuses_a_frame_number_the_controller_does_not_have(fmt, index, capsys):
    """Issue 31.9: --index 0, -1 and 99 were written out (FANUC UFRAME 1-9, KUKA BASE 1-32);
    ABB and UR frames are named (--name), not numbered."""
    assert main(['export', RIGID, '--format', fmt, '--index', index,
                 '--data-dir', str(STORE)]) == 2
    err = capsys.readouterr().err
    assert err.startswith('export: --index: ')
    assert ('--name' in err) if fmt in ('abb', 'ur') else (
        {'fanuc': 'give 1..9', 'kuka': 'give 1..32', 'yaskawa': 'give 1..63'}[fmt] in err)


@pytest.mark.parametrize('fmt, index, line', [('fanuc', '9', 'UFRAME[9]=PR[59] ;'),
                                              ('kuka', '32', 'BASE_DATA[32]={X ')])
def test_export_takes_the_last_frame_number(fmt, index, line, capsys):
    assert main(['export', RIGID, '--format', fmt, '--index', index,
                 '--data-dir', str(STORE)]) == 0
    assert any(x.startswith(line) for x in capsys.readouterr().out.splitlines())
