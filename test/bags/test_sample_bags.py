"""Every sample bag under bags/ is checked by one command, `cobot-calib replay BAG --check`
(issue 16, defect 3: on 5252a67 `replay bags/iiwa_spheres --check` failed with "cannot read
expected.yaml"). The teach, trial and landmark bags' full replays are in test_replay_check.py,
test_trial_bag.py and here; the sphere bag's check and its failure here."""
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import pytest

from cobot_calib_ros.api import replay_sphere_check

BAGS = Path(__file__).resolve().parents[2] / 'bags'
SAMPLES = sorted(p.name for p in BAGS.iterdir() if (p / 'metadata.yaml').is_file())
CHECKED_BY = {'five_point_close': 'teach', 'trial_close': 'trial',
              'landmark_multi_close': 'landmark', 'iiwa_spheres': 'sphere'}
TIMEOUT = 120.0


def replay_check(bag, *extra) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'replay',
                           str(bag), '--check', *extra],
                          capture_output=True, text=True, env=env, timeout=TIMEOUT)


def test_the_sample_bags_are_the_four_known_ones():
    assert SAMPLES == sorted(CHECKED_BY)


@pytest.mark.parametrize('name', SAMPLES)
def test_every_sample_bag_has_one_check(name):
    """Exactly one kind of check claims each sample bag, and its expected file is there."""
    from cobot_calib_ros.api import replay_check, replay_landmark_check, replay_trial_check
    from cobot_calib_ros.bags.reader import open_bag
    with open_bag(BAGS / name) as bag:
        kinds = {'trial': replay_trial_check.is_trial_bag(bag),
                 'landmark': replay_landmark_check.is_landmark_bag(bag),
                 'sphere': replay_sphere_check.is_sphere_bag(bag),
                 'teach': replay_check.is_teach_bag(bag)}
    assert [k for k, claimed in kinds.items() if claimed] == [CHECKED_BY[name]]
    expected = 'expected.json' if CHECKED_BY[name] == 'sphere' else 'expected.yaml'
    assert (BAGS / name / expected).is_file()


def test_sphere_bag_reproduces_its_identification():
    done = replay_check(BAGS / 'iiwa_spheres')
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'identified 150 poses' in done.stdout
    assert '25 parameters, largest difference' in done.stdout
    assert 'check passed' in done.stdout


def test_altered_sphere_expectation_fails_and_names_the_parameter(tmp_path):
    bag = tmp_path / 'iiwa_spheres'
    shutil.copytree(BAGS / 'iiwa_spheres', bag)
    expected = json.loads((bag / 'expected.json').read_text())
    d_2 = next(p for p in expected['identified'] if p['name'] == 'd_2')
    d_2['value'] += 1e-6                                        # d_2 off by 1 um
    (bag / 'expected.json').write_text(json.dumps(expected))
    done = replay_check(bag)
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'check FAILED' in done.stderr
    assert 'largest difference' in done.stderr and '(d_2)' in done.stderr, done.stderr


def test_sphere_check_refuses_replay_options():
    done = replay_check(BAGS / 'iiwa_spheres', '--rate', '2')
    assert done.returncode == 2
    assert 'a sphere bag is identified from its captures' in done.stderr


def test_a_bag_no_check_knows_is_named_with_the_kinds(real_bag):
    done = replay_check(real_bag('mcap', 'talker'))
    assert done.returncode == 2, done.stdout + done.stderr
    assert 'none of the sample bags --check knows' in done.stderr
    assert 'bags/iiwa_spheres' in done.stderr


def test_landmark_bag_is_checked_by_the_cli():
    """The frame within TOL_M and TOL_RAD (exit 0), from the images the live solver used
    (test_landmark_bag tests the check's failures)."""
    done = replay_check(BAGS / 'landmark_multi_close')
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'translation differs by 0.000e+00 m' in done.stdout, done.stdout
    assert 'with the images the live solver used' in done.stdout, done.stdout
