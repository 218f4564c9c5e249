"""Bags the reference rosbag2 wrote (test/data/rosbag2-test-bags), read through our reader.

Expected values from the bags' README (counts, types, stamps, contents) and, for `bag info`,
rosbag2's own end-to-end test (rosbag2_tests/test_rosbag2_info_end_to_end.cpp, cdr_test).
"""
from collections import Counter
import re
import subprocess
import sys

import pytest
from rosbags.highlevel import AnyReader

from cobot_calib_ros.bags.info import format_info, format_topic_names
from cobot_calib_ros.bags.reader import open_bag

STORAGES = ('mcap', 'sqlite3')
TALKER_START = 1585866235112411371
TALKER_DURATION = 4531096768
CDR_START = 1586406456763032325
CDR_END = 1586406456914169506          # metadata: start + duration (rosbags says +1 ns)


@pytest.mark.parametrize('storage', STORAGES)
def test_talker_all_20_messages_despite_the_qos_mismatch(storage, real_bag):
    path = real_bag(storage, 'talker')
    with open_bag(path) as bag:
        messages = list(bag.messages())
        assert bag.warnings == [] and bag.complete
        assert bag.storage_id == storage and bag.version == 4 and bag.ros_distro == ''
        assert bag.message_count == 20 and len(messages) == 20
        assert Counter(m.topic for m in messages) == {'/topic': 10, '/rosout': 10}
        assert {t.name: (t.type, t.count) for t in bag.topics.values()} == {
            '/topic': ('std_msgs/msg/String', 10), '/rosout': ('rcl_interfaces/msg/Log', 10),
            '/parameter_events': ('rcl_interfaces/msg/ParameterEvent', 0)}
        strings = [m for m in messages if m.topic == '/topic']
        assert [bag.deserialize(m.rawdata, m.msgtype).data for m in strings] == [
            f'Hello, world! {i}' for i in range(10)]
        assert strings[0].timestamp_ns == 1585866235112609068
        assert strings[-1].timestamp_ns == 1585866239643508139
        assert (bag.start_ns, bag.duration_ns) == (TALKER_START, TALKER_DURATION)
        # the QoS shown is metadata.yaml's (deadline 0), not the storage's (2147483647 s)
        assert bag.topics['/topic'].offered_qos[0].deadline.sec == 0
        # a Log decodes with the installed definition, not the bag's placeholder 'uint8 level'
        log = bag.deserialize(messages[0].rawdata, messages[0].msgtype)
        assert log.name == 'minimal_publisher' and 'Hello, world! 0' in log.msg
    # the pitfall this guards against: rosbags alone yields nothing from the directory
    with AnyReader([path]) as plain:
        assert plain.message_count == 20 and sum(1 for _ in plain.messages()) == 0


@pytest.mark.parametrize('storage', STORAGES)
def test_cdr_test_types_from_the_bags_own_definitions(storage, real_bag):
    with open_bag(real_bag(storage, 'cdr_test')) as bag:
        messages = list(bag.messages())
        assert bag.warnings == [] and bag.version == 7
        assert Counter((m.topic, m.msgtype) for m in messages) == {
            ('/test_topic', 'test_msgs/msg/BasicTypes'): 3,
            ('/array_topic', 'test_msgs/msg/Arrays'): 4}
        assert messages[0].timestamp_ns == CDR_START == bag.start_ns
        assert messages[-1].timestamp_ns == CDR_END == bag.end_ns
        basic = bag.deserialize(messages[0].rawdata, 'test_msgs/msg/BasicTypes')
        assert basic.int32_value == 123
        arrays = [bag.deserialize(m.rawdata, m.msgtype) for m in messages
                  if m.topic == '/array_topic']
        assert arrays[0].string_values == ['Complex Hello1', 'Complex Hello2', 'Complex Hello3']
        assert len(list(bag.messages(['test_topic']))) == 3      # relative name accepted


@pytest.mark.parametrize('storage,name,count', [('mcap', 'talker', 20),
                                                ('sqlite3', 'cdr_test', 7)])
def test_a_single_storage_file(storage, name, count, real_bag):
    file = next(p for p in real_bag(storage, name).iterdir() if p.suffix in ('.mcap', '.db3'))
    with open_bag(file) as bag:
        assert bag.message_count == count == len(list(bag.messages()))
        assert bag.relative_files == [file.name] and bag.storage_id == storage


@pytest.mark.parametrize('storage', STORAGES)
def test_info_matches_rosbag2s_own_expectation(storage, real_bag):
    """rosbag2_tests/test_rosbag2_info_end_to_end.cpp, info_end_to_end_test (cdr_test)."""
    with open_bag(real_bag(storage, 'cdr_test')) as bag:
        text = format_info(bag)
    expected_file = 'cdr_test_0.mcap' if storage == 'mcap' else 'cdr_test_0.db3'
    assert re.search(
        '\nFiles:             ' + expected_file
        + '\nBag size:          .*B'
        '\nStorage id:        ' + storage
        + '\nROS Distro:        unknown'
        '\nDuration:          0.151137181s'
        '\nStart:             Apr  .+ 2020 .*:.*:36.763032325 \\(1586406456.763032325\\)'
        '\nEnd:               Apr  .+ 2020 .*:.*:36.914169506 \\(1586406456.914169506\\)'
        '\nMessages:          7'
        '\nTopic information: ', text), text
    assert ('Topic: /test_topic | Type: test_msgs/msg/BasicTypes | Count: 3 | '
            'Serialization Format: cdr\n') in text
    assert ('Topic: /array_topic | Type: test_msgs/msg/Arrays | Count: 4 | '
            'Serialization Format: cdr') in text


def test_info_layout_of_talker(real_bag, monkeypatch):
    import time
    monkeypatch.setenv('TZ', 'UTC')
    time.tzset()
    try:
        with open_bag(real_bag('sqlite3', 'talker')) as bag:
            text = format_info(bag)
            names = format_topic_names(bag)
    finally:
        monkeypatch.undo()
        time.tzset()
    lines = text.split('\n')
    assert lines[0] == ''
    assert lines[1:4] == ['Files:             talker.db3', 'Bag size:          29.6 KiB',
                          'Storage id:        sqlite3']
    assert lines[4:9] == [
        'ROS Distro:        unknown', 'Duration:          4.531096768s',
        'Start:             Apr  2 2020 22:23:55.112411371 (1585866235.112411371)',
        'End:               Apr  2 2020 22:23:59.643508139 (1585866239.643508139)',
        'Messages:          20']
    assert lines[9:] == [
        'Topic information: Topic: /topic | Type: std_msgs/msg/String | Count: 10 | '
        'Serialization Format: cdr',
        '                   Topic: /rosout | Type: rcl_interfaces/msg/Log | Count: 10 | '
        'Serialization Format: cdr',
        '                   Topic: /parameter_events | Type: rcl_interfaces/msg/ParameterEvent '
        '| Count: 0 | Serialization Format: cdr',
        'Service:           0', 'Service information: ']
    assert names == '/topic\n/rosout\n/parameter_events'


def test_cli_bag_info(real_bag):
    out = subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'bag', 'info',
                          str(real_bag('mcap', 'talker'))], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('\nFiles:             talker.mcap\n')
    assert 'Messages:          20\n' in out.stdout and out.stderr == ''


def test_reading_leaves_the_data_directory_untouched(real_bag):
    before = sorted(p.name for p in real_bag('sqlite3', 'talker').iterdir())
    with open_bag(real_bag('sqlite3', 'talker')) as bag:
        list(bag.messages())
    assert sorted(p.name for p in real_bag('sqlite3', 'talker').iterdir()) == before
