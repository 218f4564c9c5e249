"""bags/iiwa_spheres: a recorded sphere-coupling session gives back the identification the live
session made (issue 12's iiwa sample bag, issue 10's `identify --source BAG`)."""
import json
from pathlib import Path

from cobot_calib_ros.cli.main import main

BAG = Path(__file__).resolve().parents[2] / 'bags' / 'iiwa_spheres'


def test_identify_from_the_bag_reproduces_the_live_identification(capsys):
    expected = json.loads((BAG / 'expected.json').read_text())
    assert main(['identify', '--source', str(BAG), '--json']) == 0
    got = json.loads(capsys.readouterr().out)
    assert got['poses'] == 150
    assert got['dropped_parameters'] == expected['dropped_parameters']
    assert [p['name'] for p in got['identified']] == [p['name'] for p in expected['identified']]
    for mine, live in zip(got['identified'], expected['identified']):
        assert abs(mine['value'] - live['value']) <= 1e-9, mine['name']


def test_a_bag_without_sphere_captures_is_refused(capsys):
    teach = BAG.parent / 'five_point_close'
    assert main(['identify', '--source', str(teach)]) == 1
    assert 'no /cobot_calib/captures poses on the spheres' in capsys.readouterr().err
