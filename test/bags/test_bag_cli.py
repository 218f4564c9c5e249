"""The bag verbs' errors and exit codes (cli/common: 1 failed, 2 usage); no node is created."""
import os
import subprocess
import sys

import pytest


def cobot_calib(*args, timeout=60):
    return subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', *args],
                          capture_output=True, text=True, timeout=timeout, env=dict(os.environ))


@pytest.mark.parametrize('verb', [('bag', 'info'), ('replay',)])
def test_no_such_bag(verb, tmp_path):
    out = cobot_calib(*verb, str(tmp_path / 'nope'))
    assert out.returncode == 1
    assert out.stderr.strip() == (f'{" ".join(verb)}: {tmp_path}/nope: no such bag (neither a '
                                  'directory nor a file); give the directory `cobot-calib '
                                  'record -o` or `ros2 bag record -o` wrote')


def test_record_needs_topics_or_all(tmp_path):
    out = cobot_calib('record', '-o', str(tmp_path / 'b'))
    assert out.returncode == 2 and 'give the topics to record, or --all' in out.stderr
    out = cobot_calib('record', '-o', str(tmp_path / 'b'), '/x', '--all')
    assert out.returncode == 2


def test_record_never_overwrites(tmp_path):
    out = cobot_calib('record', '-o', str(tmp_path), '/joint_states')
    assert out.returncode == 1 and f'{tmp_path} already exists' in out.stderr


def test_replay_usage_errors(tmp_path):
    assert cobot_calib('replay', str(tmp_path), '--rate', 'fast').returncode == 2
    assert cobot_calib('replay', str(tmp_path), '--rate', '-1').returncode == 2
    out = cobot_calib('replay', str(tmp_path), '--clock', '0')
    assert out.returncode == 2 and '--clock HZ must be > 0' in out.stderr
    out = cobot_calib('replay', str(tmp_path), '--window', '-1')
    assert out.returncode == 2 and '--window must be >= 0' in out.stderr
    out = cobot_calib('replay', str(tmp_path), '--check', '--window', '5')
    assert out.returncode == 2 and '--window do not apply' in out.stderr


def test_replay_of_an_unknown_topic_or_type(tmp_path):
    from bagutil import RELIABLE
    from cobot_calib_ros.bags.writer import BagWriter
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/x', 'foo_msgs/msg/Bar', [RELIABLE])
        bag.write('/x', b'\x00\x01\x00\x00\x07\x00\x00\x00', 1)
    out = cobot_calib('replay', str(tmp_path / 'b'), '--topics', '/y')
    assert out.returncode == 1 and 'no topic /y in the bag; it has /x' in out.stderr
    out = cobot_calib('replay', str(tmp_path / 'b'))
    assert out.returncode == 1
    assert "cannot replay /x: unknown type 'foo_msgs/msg/Bar'" in out.stderr


def test_bag_info_of_a_cut_recording_warns_on_stderr(tmp_path):
    from test_bag_errors import chunked_bag
    chunked_bag(tmp_path / 'b', 20)
    (tmp_path / 'b' / 'metadata.yaml').unlink()
    out = cobot_calib('bag', 'info', str(tmp_path / 'b'))
    assert out.returncode == 0 and 'Messages:          20\n' in out.stdout
    assert out.stderr.startswith(f'warning: {tmp_path}/b/metadata.yaml: missing')
    out = cobot_calib('bag', 'info', '--strict', str(tmp_path / 'b'))
    assert out.returncode == 1 and 'metadata.yaml: missing' in out.stderr
