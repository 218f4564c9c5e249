"""bag_player in this process (its own rclpy context) against a subscriber node: recorded QoS,
latched /tf_static, --topics, --loop, --start-paused with ~/resume; and the QoS it picks."""
import threading
import time

from geometry_msgs.msg import TransformStamped
import pytest
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import QosTime
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt64
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from bagutil import RELIABLE, cdr, joint_state
from cobot_calib_ros.bags import metadata
from cobot_calib_ros.bags.player import BagPlayer, FlowControl, replay_qos, spinning
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.writer import BagWriter

T0 = 1_795_000_000_000_000_000
MS = 1_000_000


def test_qos_as_recorded_when_all_publishers_agree():
    latched = metadata.qos(durability='transient_local', lifespan=QosTime(10, 0))
    profile = replay_qos('/rosout', [latched, latched])
    assert profile.history == HistoryPolicy.KEEP_LAST and profile.depth == 1000
    assert profile.reliability == ReliabilityPolicy.RELIABLE
    assert profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert profile.lifespan == Duration(seconds=10)
    assert profile.deadline == Duration()                 # infinite stays the default
    best_effort = replay_qos('/probe/voltage', [metadata.qos(reliability='best_effort')])
    assert best_effort.reliability == ReliabilityPolicy.BEST_EFFORT


def test_qos_fallback_and_latched_tf_static():
    mixed = [metadata.qos(), metadata.qos(durability='transient_local')]
    for offered in ([], mixed):
        assert replay_qos('/joint_states', offered).durability == DurabilityPolicy.VOLATILE
        assert replay_qos('/joint_states', offered).reliability == ReliabilityPolicy.RELIABLE
        assert replay_qos('/tf_static', offered).durability == DurabilityPolicy.TRANSIENT_LOCAL
    foxy_infinite = metadata.qos(deadline=QosTime(0x7FFFFFFF, 0xFFFFFFFF))
    assert replay_qos('/x', [foxy_infinite]).deadline == Duration()


def tf_static() -> TFMessage:
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = 'base', 'user_frame'
    t.transform.rotation.w = 1.0
    return TFMessage(transforms=[t])


@pytest.fixture(scope='module')
def sample_bag(tmp_path_factory):
    """/joint_states x 20 at 100 Hz and one /tf_static (latched) at the start."""
    path = tmp_path_factory.mktemp('bags') / 'sample'
    with BagWriter(path) as bag:
        bag.add_topic('/tf_static', 'tf2_msgs/msg/TFMessage',
                      [metadata.qos(durability='transient_local')])
        bag.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [RELIABLE])
        bag.write('/tf_static', cdr(tf_static()), T0)
        for i in range(20):
            bag.write('/joint_states', cdr(joint_state(i)), T0 + (i + 1) * 10 * MS)
    return path


class Ros:
    """A context with one node and executor, spun on demand."""

    def __init__(self, name: str, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, done, timeout=20.0) -> bool:
        deadline = time.monotonic() + timeout
        while not done() and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.02)
        return done()

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def client(bag_domain):
    ros = Ros('bag_player_test', bag_domain[0])
    yield ros
    ros.close()


@pytest.fixture
def player_context(bag_domain):
    context = Context()
    rclpy.init(context=context, domain_id=bag_domain[0])
    yield context
    rclpy.try_shutdown(context=context)


def listen(client: Ros, topic='joint_states', msg_type=JointState, durability=None):
    got = []
    profile = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    if durability is not None:
        profile.durability = durability
    client.node.create_subscription(msg_type, topic, got.append, profile, raw=True)
    return got


def play_in_thread(player: BagPlayer):
    result = {}
    thread = threading.Thread(target=lambda: result.setdefault('r', player.play()), daemon=True)
    thread.start()
    return thread, result


def test_topics_filter_and_latched_tf_static(sample_bag, client, player_context):
    joints = listen(client)
    with open_bag(sample_bag) as bag:
        player = BagPlayer(bag, rate=4.0, topics=['/joint_states', 'tf_static'],
                           wait_subscribers=10.0, context=player_context)
        with spinning(player):
            thread, result = play_in_thread(player)
            assert client.spin_until(lambda: not thread.is_alive() and len(joints) >= 20)
            # a subscriber that comes after the end still gets the latched transform
            late = listen(client, '/tf_static', TFMessage, DurabilityPolicy.TRANSIENT_LOCAL)
            assert client.spin_until(lambda: len(late) == 1)
        recorded = [m.rawdata for m in bag.messages(['/joint_states'])]
        player.destroy_node()
    assert joints == recorded
    assert late == [cdr(tf_static())]
    assert result['r'].published == 21 and result['r'].passes == 1
    assert 0.5 < result['r'].speed <= 4.1         # paced at 4x (never faster), slower if busy


def test_only_the_topics_asked_for(sample_bag, client, player_context):
    latched = listen(client, '/tf_static', TFMessage, DurabilityPolicy.TRANSIENT_LOCAL)
    joints = listen(client)
    with open_bag(sample_bag) as bag:
        player = BagPlayer(bag, rate=0, topics=['/tf_static'], wait_subscribers=10.0,
                           context=player_context)
        assert list(player.publishers_by_topic) == ['/tf_static']
        with spinning(player):
            player.play()
            assert client.spin_until(lambda: len(latched) == 1)
            client.spin_until(lambda: False, 0.3)
        player.destroy_node()
    assert joints == []


def test_start_paused_until_resume_then_loop(sample_bag, client, player_context):
    joints = listen(client)
    with open_bag(sample_bag) as bag:
        player = BagPlayer(bag, rate=10.0, loop=True, topics=['/joint_states'],
                           start_paused=True, wait_subscribers=10.0, context=player_context)
        resume = client.node.create_client(Trigger, '/bag_player/resume')
        with spinning(player):
            thread, result = play_in_thread(player)
            assert client.spin_until(resume.service_is_ready)
            client.spin_until(lambda: False, 0.5)
            assert joints == [] and player.paused            # nothing while paused
            future = resume.call_async(Trigger.Request())
            assert client.spin_until(future.done)
            assert future.result().success
            assert client.spin_until(lambda: len(joints) >= 45)  # into the third pass
            player.stop()
            thread.join(timeout=10)
        player.destroy_node()
    assert not thread.is_alive() and result['r'].passes >= 2
    with open_bag(sample_bag) as bag:
        recorded = [m.rawdata for m in bag.messages(['/joint_states'])]
    assert joints[:40] == recorded + recorded


@pytest.fixture(scope='module')
def best_effort_bag(tmp_path_factory):
    """300 /probe/joint_states at 1 kHz, recorded best effort (as probe/voltage and images)."""
    path = tmp_path_factory.mktemp('bags') / 'best_effort'
    with BagWriter(path) as bag:
        bag.add_topic('/slow/joint_states', 'sensor_msgs/msg/JointState',
                      [metadata.qos(reliability='best_effort')])
        for i in range(300):
            bag.write('/slow/joint_states', cdr(joint_state(i)), T0 + i * MS)
    return path


def test_flow_control_loses_nothing_to_a_consumer_slower_than_the_player(
        best_effort_bag, client, player_context):
    """Issue 31.5: a best-effort subscriber with a history of 3 that takes one message per
    executor round and stalls between rounds (a node on a loaded machine) gets every message of
    a bag played as fast as possible, in order, when the player keeps at most 2 of them out.
    (Without flow control it keeps only what its history held when it looked.)"""
    got = []
    client.node.create_subscription(
        JointState, '/slow/joint_states', got.append,
        QoSProfile(depth=3, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)
    stop = threading.Event()

    def slow_consumer() -> None:
        while not stop.is_set():
            client.executor.spin_once(timeout_sec=0.01)
            time.sleep(0.003)                       # busy elsewhere between rounds
    with open_bag(best_effort_bag) as bag:
        player = BagPlayer(bag, rate=0, wait_subscribers=10.0, context=player_context,
                           flow=FlowControl(2, lambda: len(got)))
        consumer = threading.Thread(target=slow_consumer, daemon=True)
        consumer.start()
        try:
            with spinning(player):
                result = player.play()
        finally:
            stop.set()
            consumer.join(timeout=5)
        recorded = [m.rawdata for m in bag.messages()]
        player.destroy_node()
    assert result.written_off == 0
    assert result.published == 300
    assert got[-300:] == recorded                   # the first may have come twice (resent)
    assert got[:len(got) - 300] == recorded[:len(got) - 300]


def test_without_flow_control_the_lost_are_counted_from_the_consumers_count(
        best_effort_bag, client, player_context):
    """The lossy mode (no window) says what was lost when the consumer publishes its running
    count on bag_player/consumed: published minus that count at the end."""
    got = []
    client.node.create_subscription(
        JointState, '/slow/joint_states', got.append,
        QoSProfile(depth=3, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)
    count = client.node.create_publisher(UInt64, 'bag_player/consumed', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    stop = threading.Event()

    def slow_consumer() -> None:
        while not stop.is_set():
            client.executor.spin_once(timeout_sec=0.01)
            count.publish(UInt64(data=len(got)))
            time.sleep(0.003)
    with open_bag(best_effort_bag) as bag:
        player = BagPlayer(bag, rate=0, wait_subscribers=10.0, context=player_context)
        consumer = threading.Thread(target=slow_consumer, daemon=True)
        consumer.start()
        try:
            assert client.spin_until(lambda: player.count_publishers(
                '/bag_player/consumed') > 0 and count.get_subscription_count() > 0)
            with spinning(player):
                result = player.play()
            time.sleep(0.5)             # the consumer's last rounds (its count is final)
        finally:
            stop.set()
            consumer.join(timeout=5)
        player.destroy_node()
    assert result.published == 300 and result.written_off == 0
    assert result.lost == 300 - len(got), (result.lost, len(got))


def test_flow_control_window_must_hold_a_message():
    with pytest.raises(ValueError, match='window must be >= 1'):
        FlowControl(0, lambda: 0)
