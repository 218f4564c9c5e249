"""`cobot-calib identify` without a suite: the real MUKCa data offline, and input errors."""
import json
from pathlib import Path

from cobot_calib_ros.cli.main import main

MUKCA = Path(__file__).resolve().parents[1] / 'data' / 'mukca-kuka-iiwa14' / 'kuka_14'


def test_real_mukca_data_held_out_error_falls_on_every_location(capsys):
    assert main(['identify', '--source', str(MUKCA), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert [f['held_out'] for f in report['folds']] == ['front', 'left_back', 'raised_left']
    for fold in report['folds']:
        assert fold['mae_after_mm'] < 0.6 * fold['mae_before_mm']
    assert abs(report['mean_mae_before_mm'] - 0.778) < 1e-3   # the data README's nominal
    assert report['mean_mae_after_mm'] < 0.3
    print(f"\nMUKCa held-out MAE {report['mean_mae_before_mm']:.3f} -> "
          f"{report['mean_mae_after_mm']:.3f} mm (published about 0.2 mm)")


def test_wrong_sources_say_what_is_accepted(capsys, tmp_path):
    assert main(['identify', '--source', str(tmp_path / 'missing')]) == 2
    assert 'not mock and not a folder' in capsys.readouterr().err
    assert main(['identify', '--source', str(tmp_path)]) == 2
    assert 'not a collection folder' in capsys.readouterr().err
    assert main(['identify', '--source', str(MUKCA), '--urdf', str(tmp_path / 'x.urdf')]) == 2
    assert 'give the nominal URDF with --urdf' in capsys.readouterr().err
    assert main(['identify', '--max-configs', '-1']) == 2
