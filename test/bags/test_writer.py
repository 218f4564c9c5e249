"""Bags we write: read back identically by rosbags' AnyReader and by the mcap library, with
the metadata.yaml, schemas, channel metadata and type hashes of Jazzy's rosbag2."""
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
import yaml

from bagutil import LATCHED, RELIABLE, cdr, joint_state, user_frame
from cobot_calib_ros.bags import interfaces
from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.writer import BagWriter

JS, UF = 'sensor_msgs/msg/JointState', 'cobot_calib_msgs/msg/UserFrameCalibration'
T0 = 1_795_000_000_000_000_000
INFINITE = {'sec': 9223372036, 'nsec': 854775807}
# rmw's qos_string_conversions vocabulary (what rosbag2 v9 metadata decodes), plus "unknown"
POLICY_WORDS = {
    'history': {'system_default', 'keep_last', 'keep_all', 'unknown'},
    'reliability': {'system_default', 'reliable', 'best_effort', 'best_available', 'unknown'},
    'durability': {'system_default', 'transient_local', 'volatile', 'best_available', 'unknown'},
    'liveliness': {'system_default', 'automatic', 'manual_by_topic', 'best_available',
                   'unknown'}}


def write_bag(path: Path, compression=None):
    """JointState x 50 (1 kHz) and one latched UserFrameCalibration; what was written."""
    written = []
    with BagWriter(path, compression=compression) as bag:
        bag.add_topic('/joint_states', JS, [RELIABLE])
        bag.add_topic('/user_frame', UF, [LATCHED, LATCHED])
        for i in range(50):
            written.append(('/joint_states', JS, T0 + i * 1_000_000, cdr(joint_state(i))))
            if i == 20:
                written.append(('/user_frame', UF, T0 + i * 1_000_000 + 1, cdr(user_frame())))
        for topic, _, stamp, data in written:
            bag.write(topic, data, stamp, stamp - 250_000)
    return written


@pytest.fixture(params=[None, 'zstd'], ids=['plain', 'zstd'])
def bag(request, tmp_path):
    path = tmp_path / 'run1'
    return path, write_bag(path, request.param), request.param


def test_layout_as_ros2_bag_record(bag):
    path, _, _ = bag
    assert sorted(p.name for p in path.iterdir()) == ['metadata.yaml', 'run1_0.mcap']


def test_anyreader_reads_it_back_identically(bag):
    path, written, _ = bag
    with AnyReader([path]) as reader:                  # checks the type hashes too
        got = [(c.topic, c.msgtype, t, bytes(d)) for c, t, d in reader.messages()]
        assert got == written
        for conn, _, data in reader.messages():
            msg = reader.deserialize(data, conn.msgtype)
        assert reader.message_count == 51
        frame = [reader.deserialize(d, c.msgtype) for c, _, d in reader.messages()
                 if c.topic == '/user_frame'][0]
    assert frame.method == 'rigid' and [r.name for r in frame.residuals] == ['P1', 'P2', 'P3']
    assert list(msg.position) == list(joint_state(49).position)


def test_our_reader_reads_it_back_identically(bag):
    path, written, _ = bag
    with open_bag(path, strict=True) as reader:
        assert [tuple(m) for m in reader.messages()] == written
        assert reader.version == 9 and reader.ros_distro and reader.complete
        assert (reader.start_ns, reader.end_ns) == (T0, T0 + 49_000_000)


def test_mcap_library_sees_rosbag2s_records(bag):
    path, written, compression = bag
    with open(path / 'run1_0.mcap', 'rb') as f:
        reader = make_reader(f)
        assert reader.get_header().profile == 'ros2'
        got = [(c.topic, s.name, m.log_time, m.data, m.publish_time, s, c)
               for s, c, m in reader.iter_messages()]
        summary = reader.get_summary()
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert [(t, n, lt, d) for t, n, lt, d, *_ in got] == [(a, b, c, d) for a, b, c, d in written]
    assert all(pt == lt - 250_000 for _, _, lt, _, pt, _, _ in got)
    schemas = {s.name: s for *_, s, _ in got}
    channels = {c.topic: c for *_, c in got}
    for name, schema in schemas.items():
        assert schema.encoding == 'ros2msg'
        assert schema.data.decode() == interfaces.full_text(name)
    js = schemas[JS].data.decode()
    assert js.startswith(interfaces.msg_text(JS))
    assert '=' * 80 + '\nMSG: std_msgs/Header\n' in js
    assert '=' * 80 + '\nMSG: builtin_interfaces/Time\n' in js
    uf = schemas[UF].data.decode()
    for nested in ('cobot_calib_msgs/PointResidual', 'cobot_calib_msgs/SurfaceModel',
                   'geometry_msgs/TransformStamped', 'geometry_msgs/Quaternion',
                   'std_msgs/Header'):
        assert f'\nMSG: {nested}\n' in uf
    for topic, msgtype in (('/joint_states', JS), ('/user_frame', UF)):
        meta = channels[topic].metadata
        assert meta['topic_type_hash'] == interfaces.installed_type_hash(msgtype)
        assert channels[topic].message_encoding == 'cdr'
        profiles = yaml.safe_load(meta['offered_qos_profiles'])
        assert len(profiles) == (1 if topic == '/joint_states' else 2)
        assert profiles[0]['durability'] == ('volatile' if topic == '/joint_states'
                                             else 'transient_local')
    assert {c.compression for c in summary.chunk_indexes} == {compression or ''}
    assert summary.statistics.message_count == 51
    stored = yaml.safe_load(records['rosbag2']['serialized_metadata'])
    assert stored['version'] == 9 and stored['message_count'] == 51


def test_metadata_yaml_is_jazzys_version_9(bag):
    path, written, _ = bag
    text = (path / 'metadata.yaml').read_text()
    info = yaml.safe_load(text)['rosbag2_bagfile_information']
    # the keys in the order yaml-cpp writes them (rosbag2_storage/yaml.hpp, BagMetadata)
    assert list(info) == ['version', 'storage_identifier', 'duration', 'starting_time',
                          'message_count', 'topics_with_message_count', 'compression_format',
                          'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                          'ros_distro']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['message_count'] == 51
    assert info['starting_time'] == {'nanoseconds_since_epoch': T0}
    assert info['duration'] == {'nanoseconds': 49_000_000}
    assert info['relative_file_paths'] == ['run1_0.mcap']
    assert info['files'] == [{'path': 'run1_0.mcap', 'starting_time': info['starting_time'],
                              'duration': info['duration'], 'message_count': 51}]
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['custom_data'] is None
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {n: t['message_count'] for n, t in topics.items()} == {'/joint_states': 50,
                                                                  '/user_frame': 1}
    for name, msgtype in (('/joint_states', JS), ('/user_frame', UF)):
        meta = topics[name]['topic_metadata']
        assert list(meta) == ['name', 'type', 'serialization_format', 'offered_qos_profiles',
                              'type_description_hash']
        assert meta['type'] == msgtype and meta['serialization_format'] == 'cdr'
        assert meta['type_description_hash'] == interfaces.installed_type_hash(msgtype)
        assert meta['type_description_hash'].startswith('RIHS01_')
        profiles = meta['offered_qos_profiles']
        assert isinstance(profiles, list) and profiles      # v9: a list, not a string
        for profile in profiles:
            assert list(profile) == ['history', 'depth', 'reliability', 'durability',
                                     'deadline', 'lifespan', 'liveliness',
                                     'liveliness_lease_duration',
                                     'avoid_ros_namespace_conventions']
            for policy, words in POLICY_WORDS.items():
                assert profile[policy] in words
            assert profile['deadline'] == profile['lifespan'] == INFINITE
            assert profile['liveliness_lease_duration'] == INFINITE
    assert topics['/joint_states']['topic_metadata']['offered_qos_profiles'][0] == {
        'history': 'unknown', 'depth': 0, 'reliability': 'reliable', 'durability': 'volatile',
        'deadline': INFINITE, 'lifespan': INFINITE, 'liveliness': 'automatic',
        'liveliness_lease_duration': INFINITE, 'avoid_ros_namespace_conventions': False}
    # yaml-cpp's block layout, as in Jazzy's files
    assert '\n  topics_with_message_count:\n    - topic_metadata:\n        name: /joint_states\n' \
        in text
    assert '\n        offered_qos_profiles:\n          - history: unknown\n            depth: 0\n' \
        in text
    assert '\n  custom_data: ~\n  ros_distro: ' in text


def test_type_hashes_agree_with_rosbags(bag):
    store = interfaces.typestore()
    for msgtype in (JS, UF, 'tf2_msgs/msg/TFMessage', 'cobot_calib_msgs/msg/ProbeVoltage'):
        assert interfaces.installed_type_hash(msgtype) == store.hash_rihs01(msgtype)


def test_an_existing_directory_is_refused(tmp_path):
    (tmp_path / 'taken').mkdir()
    with pytest.raises(BagError, match='taken: already exists'):
        BagWriter(tmp_path / 'taken')


def test_a_type_without_definition_gets_an_empty_schema(tmp_path):
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/x', 'foo_msgs/msg/Bar', [RELIABLE])
        bag.write('/x', b'\x00\x01\x00\x00\x07\x00\x00\x00', T0)
    # a bag with no definition at all: AnyReader wants a typestore for it
    with AnyReader([tmp_path / 'b'], default_typestore=interfaces.typestore()) as reader:
        assert [(c.topic, c.msgtype, t) for c, t, _ in reader.messages()] == [
            ('/x', 'foo_msgs/msg/Bar', T0)]


def test_an_empty_bag_is_what_rosbag2_writes(tmp_path):
    with BagWriter(tmp_path / 'empty') as bag:
        bag.add_topic('/joint_states', JS, [RELIABLE])
    info = yaml.safe_load((tmp_path / 'empty' / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert info['message_count'] == 0 and info['duration'] == {'nanoseconds': 0}
    assert info['starting_time'] == {'nanoseconds_since_epoch': 2**63 - 1}
    with open_bag(tmp_path / 'empty') as reader:
        assert reader.message_count == 0 and list(reader.messages()) == []
