"""tf2_msgs/msg/TFMessage as on ROS 2 Jazzy, and StaticBroadcaster on /tf_static.

The broadcaster tests run in this process on a ROS domain of their own (domain_coordinator),
not the session's: the node suite of test/nodes may latch its own /tf_static there.
"""
import importlib
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import time

import domain_coordinator
from geometry_msgs.msg import TransformStamped
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from tf2_msgs.msg import TFMessage

from cobot_calib_ros.ros.tf_static import QOS, TOPIC, StaticBroadcaster

# RIHS01 hash of tf2_msgs/msg/TFMessage from a real rosidl build of ros2/geometry2's tf2_msgs:
# github.com/micro-ROS/micro_ros_arduino, src/tf2_msgs/msg/detail/tf_message__struct.h at
# commit 57e9c210191a909ab7fddaa2b80f10d40ff3ebb7 (a Rolling build of 2023-03-25:
# rosidl_generator_c wrote tf2_msgs__msg__TFMessage__TYPE_HASH = {1, {0xe3, 0x69, ..., 0x87}}).
# TFMessage and the types it nests have not changed since. For Jazzy, the same string appears in
# public `ros2 topic info --verbose /tf_static` logs of a Jazzy/Nav2 system and as
# type_description_hash in a Jazzy rosbag2 metadata.yaml; rosbags' ROS2_JAZZY typestore computes
# it too (test below).
TFMESSAGE_HASH = 'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087'
# The other tf2_msgs message, same micro-ROS commit (tf2_error__struct.h).
TF2ERROR_HASH = 'RIHS01_db2485e7d6a0ec75bf087e058ee45df682acc3a621ca7780503d10aac141809a'

TIMEOUT = 10.0  # [s] for discovery and a latched message to arrive


def _generated_hash(type_name: str) -> str:
    """The hash rosidl_generator_type_description wrote in <prefix>/share/<pkg>/<kind>/<T>.json,
    <prefix> being the install the Python package was imported from (the venv, or /opt/ros/...)."""
    pkg, kind, name = type_name.split('/')
    module = Path(importlib.import_module(pkg).__file__).resolve()
    path = next(p / 'share' / pkg / kind / f'{name}.json' for p in module.parents
                if (p / 'share' / pkg / 'package.xml').is_file())
    hashes = json.loads(path.read_text())['type_hashes']
    return {h['type_name']: h['hash_string'] for h in hashes}[type_name]


def test_tfmessage_type_hash_is_jazzy():
    assert _generated_hash('tf2_msgs/msg/TFMessage') == TFMESSAGE_HASH
    assert _generated_hash('tf2_msgs/msg/TF2Error') == TF2ERROR_HASH


def test_rosbags_jazzy_typestore_agrees():
    """An independent RIHS01 implementation (rosbags) over its own Jazzy definitions."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    assert store.hash_rihs01('tf2_msgs/msg/TFMessage') == TFMESSAGE_HASH


def _transform(parent, child, x=0.0, y=0.0, z=0.0, yaw=0.0) -> TransformStamped:
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = x, y, z
    t.transform.rotation.z, t.transform.rotation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return t


def test_cdr_matches_rosbags_jazzy():
    """Same CDR layout as rosbag2/rosbags read and write for Jazzy's TFMessage."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    msg = TFMessage(transforms=[_transform('base', 'user_frame', 0.1, -0.2, 0.3, 0.5),
                                _transform('base', 'tool', z=0.25)])
    msg.transforms[0].header.stamp.sec, msg.transforms[0].header.stamp.nanosec = 12, 345
    raw = serialize_message(msg)
    theirs = store.deserialize_cdr(raw, 'tf2_msgs/msg/TFMessage')
    assert [t.child_frame_id for t in theirs.transforms] == ['user_frame', 'tool']
    assert theirs.transforms[0].header.stamp.nanosec == 345
    assert theirs.transforms[0].transform.translation.y == -0.2
    back = deserialize_message(bytes(store.serialize_cdr(theirs, 'tf2_msgs/msg/TFMessage')),
                               TFMessage)
    assert back == msg


@pytest.fixture(scope='module')
def ros():
    """A context on a domain of its own; yields (context, executor)."""
    with domain_coordinator.domain_id() as domain:
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        executor = SingleThreadedExecutor(context=context)
        try:
            yield context, executor
        finally:
            executor.shutdown()
            rclpy.try_shutdown(context=context)


class Listener:
    """A late-joining /tf_static subscriber with tf2's StaticListenerQoS (depth 100, latched)."""

    QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

    def __init__(self, ros, name):
        context, self.executor = ros
        self.node = rclpy.create_node(name, context=context)
        self.messages: list[TFMessage] = []
        self.node.create_subscription(TFMessage, TOPIC, self.messages.append, self.QOS)
        self.executor.add_node(self.node)

    def spin_until(self, predicate, timeout=TIMEOUT) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if predicate():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def spin_for(self, seconds):
        self.spin_until(lambda: False, seconds)

    def close(self):
        self.executor.remove_node(self.node)
        self.node.destroy_node()


def _frames(msg: TFMessage) -> dict[str, tuple]:
    return {t.child_frame_id: (t.header.frame_id, t.transform.translation.x,
                               t.transform.translation.y, t.transform.translation.z)
            for t in msg.transforms}


@pytest.fixture
def broadcaster(ros):
    context, executor = ros
    node = rclpy.create_node('tf_static_test_publisher', context=context)
    executor.add_node(node)
    yield StaticBroadcaster(node)
    executor.remove_node(node)
    node.destroy_node()


def test_publisher_qos_and_type_on_the_graph(ros, broadcaster):
    assert broadcaster.publisher.topic_name == '/tf_static'
    qos = broadcaster.publisher.qos_profile
    assert (qos.history, qos.depth) == (HistoryPolicy.KEEP_LAST, 1)
    assert qos.reliability == ReliabilityPolicy.RELIABLE
    assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert QOS == qos
    # What rmw tells the graph (as `ros2 topic info -v` shows it): type, hash, QoS.
    listener = Listener(ros, 'tf_static_graph_probe')
    try:
        def found():
            return listener.node.get_publishers_info_by_topic(TOPIC)
        assert listener.spin_until(lambda: len(found()) == 1)
        info = found()[0]
        assert info.topic_type == 'tf2_msgs/msg/TFMessage'
        assert str(info.topic_type_hash) == TFMESSAGE_HASH
        assert info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    finally:
        listener.close()


def test_late_subscriber_gets_latched_set_and_resend_replaces(ros, broadcaster):
    broadcaster.send(_transform('base', 'user_frame', 0.5, 0.1, 0.0, yaw=0.3))
    broadcaster.send([_transform('base', 'probe_table', 0.8, -0.2, 0.05)])

    # Joins after both sends: gets one message (publisher depth 1) with both child frames.
    late = Listener(ros, 'tf_static_late_joiner')
    try:
        assert late.spin_until(lambda: late.messages), 'latched /tf_static never arrived'
        late.spin_for(0.3)
        assert len(late.messages) == 1
        assert _frames(late.messages[0]) == {'user_frame': ('base', 0.5, 0.1, 0.0),
                                             'probe_table': ('base', 0.8, -0.2, 0.05)}

        # Resending a child frame replaces it; the set (order of first send) is republished.
        broadcaster.send(_transform('base', 'user_frame', 0.6, 0.1, 0.0))
        assert late.spin_until(lambda: len(late.messages) == 2)
        assert [t.child_frame_id for t in late.messages[1].transforms] == ['user_frame',
                                                                           'probe_table']
        assert _frames(late.messages[1])['user_frame'] == ('base', 0.6, 0.1, 0.0)
    finally:
        late.close()

    # A second late joiner sees only the latest set.
    later = Listener(ros, 'tf_static_later_joiner')
    try:
        assert later.spin_until(lambda: later.messages)
        later.spin_for(0.3)
        assert len(later.messages) == 1
        assert _frames(later.messages[0]) == {'user_frame': ('base', 0.6, 0.1, 0.0),
                                              'probe_table': ('base', 0.8, -0.2, 0.05)}
    finally:
        later.close()


def test_send_copies_and_rejects_what_tf2_ignores(broadcaster):
    t = _transform('base', 'user_frame', 1.0)
    broadcaster.send(t)
    t.transform.translation.x = 2.0  # the caller's message is not the latched one
    assert broadcaster.transforms[0].transform.translation.x == 1.0

    bad = [_transform('base', 'base'), _transform('', 'x'), _transform('base', '/'),
           _transform('base', 'x', x=math.nan), _transform('base', 'x', x=math.inf)]
    unnormalised = _transform('base', 'x')
    unnormalised.transform.rotation.w = 0.0
    for t in [*bad, unnormalised]:
        with pytest.raises(ValueError):
            broadcaster.send([_transform('base', 'other'), t])
    with pytest.raises(TypeError):
        broadcaster.send([TFMessage()])
    # Nothing of a rejected batch was kept.
    assert [t.child_frame_id for t in broadcaster.transforms] == ['user_frame']


# -- tools/interface_provider.py: when `make setup` builds interfaces/tf2_msgs, and when not --

PROVIDER = Path(__file__).resolve().parents[2] / 'tools' / 'interface_provider.py'
FAKE = 'fake_iface_pkg_for_test'


def _provider(venv, pkg, inherit=False, **env) -> str:
    """Its answer, in this environment (inherit) or in a clean one plus ``env``."""
    environ = dict(os.environ)
    if not inherit:
        environ.pop('PYTHONPATH', None)
        environ.pop('AMENT_PREFIX_PATH', None)
    environ.update(env)
    done = subprocess.run([sys.executable, str(PROVIDER), str(venv), pkg], env=environ,
                          capture_output=True, text=True, timeout=60, check=True)
    return done.stdout.strip()


def _fake_package(root: Path) -> Path:
    (root / FAKE / 'msg').mkdir(parents=True)
    (root / FAKE / '__init__.py').touch()
    (root / FAKE / 'msg' / '__init__.py').touch()
    return root / FAKE


def test_provider_decides_build_or_skip(tmp_path):
    venv = Path(sys.prefix)
    # Not anywhere: build.
    assert _provider(venv, FAKE) == 'none'
    # Importable from elsewhere (a sourced ROS install, a wheel): skip the build.
    foreign = _fake_package(tmp_path / 'ros' / 'site-packages')
    assert _provider(venv, FAKE, PYTHONPATH=str(foreign.parent)) == f'foreign {foreign}'
    # Our own earlier build (inside VENV_DIR, with the marker): rebuild.
    mine = tmp_path / 'venv'
    ours = _fake_package(mine / 'lib' / 'site-packages')
    (mine / 'share' / FAKE).mkdir(parents=True)
    (mine / 'share' / FAKE / 'cobot_calib_ros.vendored').touch()
    assert _provider(mine, FAKE, PYTHONPATH=str(ours.parent)) == f'ours {ours}'
    # Only in some ament index, not importable by this Python: build ours (and say so).
    prefix = tmp_path / 'other_ros'
    (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages').mkdir(parents=True)
    (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / FAKE).touch()
    assert _provider(venv, FAKE, AMENT_PREFIX_PATH=str(prefix)) == f'index-only {prefix}'


def test_provider_sees_the_tf2_msgs_in_use():
    import tf2_msgs
    where = Path(tf2_msgs.__file__).resolve().parent
    venv = Path(sys.prefix).resolve()
    ours = (where.is_relative_to(venv)
            and (venv / 'share' / 'tf2_msgs' / 'cobot_calib_ros.vendored').is_file())
    assert _provider(venv, 'tf2_msgs', inherit=True) == f'{"ours" if ours else "foreign"} {where}'
