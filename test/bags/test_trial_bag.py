"""bags/trial_close: a recorded repeatability trial gives back its RP (issue 12's trial sample
bag). `cobot-calib replay BAG --check` replays the probe voltages through proximity_sensor (own
domain, sim time), rebuilds every probe average the trial took and recomputes ISO 9283 RP; a
changed expected.yaml is caught. The offline tests need no ROS graph."""
import os
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
import yaml

from cobot_calib_ros.api import replay_trial_check as check
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.core.repeatability import point_statistics

SAMPLE = Path(__file__).resolve().parents[2] / 'bags' / 'trial_close'
TIMEOUT = 120.0


def run_check(bag, *extra) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'replay',
                           str(bag), '--check', *extra],
                          capture_output=True, text=True, env=env, timeout=TIMEOUT)


def test_sample_bag_is_short_and_light():
    size = sum(p.stat().st_size for p in SAMPLE.iterdir())
    assert size < 300_000, size
    with open_bag(SAMPLE) as bag:
        assert set(bag.topics) == {check.VOLTAGE_TOPIC, check.MARKS_TOPIC, check.STATS_TOPIC}
        assert check.is_trial_bag(bag)


def test_recorded_voltages_rebuild_every_live_average_offline():
    """The bag alone (proximity_sensor's conversion and averaging, no node): every mark to the
    bit, and the trial's RP equal to the last recorded /repeatability."""
    _, expected = check.read_expected(SAMPLE)
    with open_bag(SAMPLE) as bag:
        marks = check.read_marks(bag)
        rebuilt = check.rebuild_marks(marks, check.bag_samples(bag, expected['proximity_sensor']))
        final = [bag.deserialize(m.rawdata, m.msgtype)
                 for m in bag.messages([check.STATS_TOPIC])][-1]
    assert [check.mark_difference(m, r) for m, r in zip(marks, rebuilt)] == [''] * len(marks)
    m, n = len(expected['point_names']), expected['cycles']
    stats = point_statistics(check.distances(expected['readings'], rebuilt, m, n))
    assert stats.cycles == n == final.cycles_done
    assert list(stats.rp) == list(final.rp) == expected['rp']
    assert stats.rp_all == final.rp_all == expected['rp_all']


def test_sample_bag_reproduces_its_repeatability():
    done = run_check(SAMPLE)
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'all equal to the live ones' in done.stdout, done.stdout
    assert 'largest difference 0.000e+00 m' in done.stdout, done.stdout
    assert 'check passed' in done.stdout


def test_altered_expectation_fails_and_names_the_difference(tmp_path):
    bag = tmp_path / 'trial_close'
    shutil.copytree(SAMPLE, bag)
    expected = yaml.safe_load((bag / 'expected.yaml').read_text())
    expected['rp'][2] += 2e-6                           # 2 um on RP_3
    (bag / 'expected.yaml').write_text(yaml.safe_dump(expected))
    done = run_check(bag)
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'check FAILED' in done.stderr
    assert 'largest difference 0.002000 mm' in done.stderr, done.stderr
    assert 'expected RP_i' in done.stderr and 'recorded RP_i' in done.stderr


def test_readings_paired_with_the_wrong_averages_fail():
    """Offline, with the check's own pairing (expected.yaml's mark per reading) and statistics:
    the replay rebuilds the averages to the bit (test_sample_bag_reproduces_its_repeatability),
    so one reading paired with the average before its own moves RP past the check's tolerance,
    which the check reports as FAILED (test_altered_expectation_fails_and_names_the_difference)."""
    _, expected = check.read_expected(SAMPLE)
    expected['readings'][0]['mark'] -= 1               # the average before P1's of cycle 1
    with open_bag(SAMPLE) as bag:
        marks = check.read_marks(bag)
        rebuilt = check.rebuild_marks(marks, check.bag_samples(bag, expected['proximity_sensor']))
    m, n = len(expected['point_names']), expected['cycles']
    stats = point_statistics(check.distances(expected['readings'], rebuilt, m, n))
    worst = max(np.max(np.abs(stats.rp - np.array(expected['rp']))),
                abs(stats.rp_all - expected['rp_all']))
    assert worst > check.TOL_M


def test_trial_check_needs_a_finite_rate():
    done = run_check(SAMPLE, '--rate', 'max')
    assert done.returncode == 2
    assert 'finite --rate' in done.stderr
