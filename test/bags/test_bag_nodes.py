"""bag_player and bag_recorder as `ros2 run` executables (<prefix>/lib/cobot_calib_ros/, from
setup.py's console_scripts): parameters with descriptions, a recording of what the player
plays, clear errors without the required parameter."""
from pathlib import Path
import signal
import subprocess
import sys

import pytest
import rclpy
from rclpy.context import Context

from cobot_calib_ros.bags.player import BagPlayer
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.recorder import BagRecorder

LIB = Path(sys.prefix) / 'lib' / 'cobot_calib_ros'
SAMPLE = Path(__file__).resolve().parents[2] / 'bags' / 'trial_close'
MARKS, STATS = '/cobot_calib/probe_averages', '/repeatability'
PLAYER_PARAMETERS = ('bag', 'rate', 'loop', 'topics', 'clock_hz', 'start_paused',
                     'wait_subscribers')
RECORDER_PARAMETERS = ('output', 'topics', 'all_topics', 'include_hidden', 'compression',
                       'duration')


def executable(name: str) -> str:
    path = LIB / name
    if not path.exists():
        pytest.skip(f'{path} not installed (pip install -e . and tools/install_ros_prefix.py)')
    return str(path)


def test_parameters_are_declared_with_descriptions(bag_domain, tmp_path):
    context = Context()
    rclpy.init(context=context, domain_id=bag_domain[0])
    try:
        with open_bag(SAMPLE) as bag:
            player = BagPlayer(bag, rate=3.0, topics=[MARKS], context=context)
            recorder = BagRecorder(str(tmp_path / 'r'), [MARKS], context=context)
            try:
                for node, names in ((player, PLAYER_PARAMETERS),
                                    (recorder, RECORDER_PARAMETERS)):
                    for name in names:
                        descriptor = node.describe_parameter(name)
                        assert descriptor.description and descriptor.read_only, name
                assert player.get_parameter('rate').value == 3.0
                assert player.get_parameter('topics').value == [MARKS]
                assert player.get_parameter('bag').value == str(SAMPLE)
                assert recorder.get_parameter('output').value == str(tmp_path / 'r')
                assert '[s]' in recorder.describe_parameter('duration').description
            finally:
                player.destroy_node()
                recorder.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_recorder_records_what_the_player_plays(bag_domain, tmp_path):
    player, recorder = executable('bag_player'), executable('bag_recorder')
    _, env = bag_domain
    out = tmp_path / 'copy'
    rec = subprocess.Popen([recorder, '--ros-args', '-p', f'output:={out}',
                            '-p', f'topics:=[{MARKS}, {STATS}]', '-p', 'compression:=zstd'],
                           env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:     # the player waits until the recorder (starting meanwhile) matches every topic
        play = subprocess.run([player, '--ros-args', '-p', f'bag:={SAMPLE}', '-p', 'rate:=0.0',
                               '-p', f'topics:=[{MARKS}, {STATS}]',
                               '-p', 'wait_subscribers:=60.0'],
                              env=env, capture_output=True, text=True, timeout=60)
        assert play.returncode == 0, play.stdout + play.stderr
        assert 'published 50 messages' in play.stdout + play.stderr
    finally:
        rec.send_signal(signal.SIGINT)
        log, _ = rec.communicate(timeout=30)
    assert rec.returncode == 0, log
    with open_bag(SAMPLE) as original, open_bag(out) as copy:
        for topic in (MARKS, STATS):
            assert copy.topics[topic].count == original.topics[topic].count, log
            assert [m.rawdata for m in copy.messages([topic])] == \
                [m.rawdata for m in original.messages([topic])]


def test_required_parameters_are_named(bag_domain):
    _, env = bag_domain
    done = subprocess.run([executable('bag_player')], env=env, capture_output=True, text=True,
                          timeout=30)
    assert done.returncode == 1 and 'bag_player: parameter bag' in done.stderr, done.stderr
    done = subprocess.run([executable('bag_recorder')], env=env, capture_output=True,
                          text=True, timeout=30)
    assert done.returncode == 1 and 'bag_recorder: parameter output' in done.stderr, \
        done.stderr
