"""End to end over DDS (this session's private domain): `cobot-calib record` a JointState
publisher for about a second, then `cobot-calib replay --rate 2 --clock` to a subscriber in
this process: same count, same bytes, in half the time, /clock monotonic."""
import re
import signal
import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from bagutil import joint_state
from cobot_calib_ros.bags.reader import open_bag

COUNT = 500
HZ = 500.0
TIMEOUT = 60.0


def cobot_calib(*args) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


@pytest.fixture(scope='module')
def ros(bag_domain):
    context = Context()
    rclpy.init(context=context, domain_id=bag_domain[0])
    node = rclpy.create_node('bag_test_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown(timeout_sec=1.0)
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def spin_until(executor, done, timeout) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return done()


def record(node, executor, bag_dir, env, executor_kind) -> list[JointState]:
    """Publish COUNT JointStates at HZ while `cobot-calib record` runs; what was published."""
    # a history that holds them all: what the middleware failed to deliver on a starved
    # machine can still be repaired (at 1 kHz with depth 100, bench_bag sees such losses)
    pub = node.create_publisher(JointState, 'joint_states',
                                QoSProfile(depth=COUNT, reliability=ReliabilityPolicy.RELIABLE))
    recorder = subprocess.Popen(cobot_calib('record', '-o', str(bag_dir), '/joint_states'),
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                env=dict(env, COBOT_CALIB_EXECUTOR=executor_kind))
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() >= 1, TIMEOUT), \
            'the recorder did not subscribe'
        published = []
        start = time.monotonic()
        for i in range(COUNT):
            msg = joint_state(i)
            pub.publish(msg)
            published.append(msg)
            delay = start + (i + 1) / HZ - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        assert pub.wait_for_all_acked(Duration(seconds=10))
        info = node.get_publishers_info_by_topic('/joint_states')
        published_hash = str(next(p for p in info if p.node_name == node.get_name())
                             .topic_type_hash)
        recorder.send_signal(signal.SIGINT)             # Ctrl-C closes the bag
        out, _ = recorder.communicate(timeout=TIMEOUT)
    finally:
        if recorder.poll() is None:
            recorder.kill()
        node.destroy_publisher(pub)
    assert recorder.returncode == 0, out
    assert f'bag {bag_dir}: {COUNT} messages on 1 topics' in out, out
    return published, published_hash


@pytest.mark.parametrize('executor_kind', ['single', 'events'])
def test_record_then_replay_at_twice_the_speed(ros, bag_domain, tmp_path, executor_kind):
    """The recorder on either node executor (ros.spin); the player has its own."""
    node, executor = ros
    bag_dir = tmp_path / 'recorded'
    published, published_hash = record(node, executor, bag_dir, bag_domain[1], executor_kind)

    with open_bag(bag_dir, strict=True) as bag:
        recorded = list(bag.messages())
        decoded = [bag.deserialize(m.rawdata, m.msgtype) for m in recorded]
        topic = bag.topics['/joint_states']
    assert len(recorded) == COUNT
    assert [list(m.position) for m in decoded] == [list(m.position) for m in published]
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in decoded] == [
        (m.header.stamp.sec, m.header.stamp.nanosec) for m in published]
    assert topic.type_hash == published_hash            # what rcl reports for the publisher
    assert [(q.reliability.name, q.durability.name) for q in topic.offered_qos] == [
        ('RELIABLE', 'VOLATILE')]
    span_s = (recorded[-1].timestamp_ns - recorded[0].timestamp_ns) / 1e9
    assert 0.8 < span_s < 5.0                            # 1 s of publishing, give or take

    received, clocks = [], []
    sub = node.create_subscription(
        JointState, 'joint_states', lambda data: received.append((time.monotonic(), data)),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE), raw=True)
    clock_sub = node.create_subscription(
        Clock, '/clock', lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec),
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
    player = subprocess.Popen(cobot_calib('replay', str(bag_dir), '--rate', '2', '--clock',
                                          '--wait-subscribers', '30'),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=bag_domain[1])
    try:
        spin_until(executor, lambda: player.poll() is not None and len(received) >= COUNT,
                   TIMEOUT)
        spin_until(executor, lambda: False, 0.2)          # stragglers, duplicates
        out, _ = player.communicate(timeout=TIMEOUT)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_subscription(sub)
        node.destroy_subscription(clock_sub)
    assert player.returncode == 0, out
    assert f'published {COUNT} messages' in out, out
    assert [data for _, data in received] == [m.rawdata for m in recorded]
    # paced at 2x, not as fast as possible (which takes a few ms): the player's own measure,
    # and what arrived here (loosely: this process may be slow to take them on a busy machine)
    speed = float(re.search(r'\(([\d.]+)x real time\)', out).group(1))
    assert 1.0 < speed <= 2.05, out
    replay_s = received[-1][0] - received[0][0]
    assert span_s / 4 < replay_s < span_s / 2 + 2.0, (span_s, replay_s)
    assert len(clocks) >= 5, clocks
    assert clocks == sorted(clocks)
    assert recorded[0].timestamp_ns <= clocks[0] and clocks[-1] <= recorded[-1].timestamp_ns


def test_replay_with_a_window_loses_nothing_to_a_slow_subscriber(ros, bag_domain, tmp_path):
    """Issue 31.5 (a bag without metadata.yaml replayed 9,596 of 10,000 to a subscriber): with
    --window the player in its own process waits for the subscriber's count on
    /bag_player/consumed, so a keep-last 20 subscriber that stalls between executor rounds gets
    every message of a bag played as fast as possible."""
    from std_msgs.msg import UInt64

    from bagutil import cdr, RELIABLE
    from cobot_calib_ros.bags.writer import BagWriter
    node, executor = ros
    count = 1000
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/window/joint_states', 'sensor_msgs/msg/JointState', [RELIABLE])
        for i in range(count):
            bag.write('/window/joint_states', cdr(joint_state(i)), 1_795_000_000 * 10**9 + i)
    (tmp_path / 'b' / 'metadata.yaml').unlink()         # read from the mcap alone
    got = []
    sub = node.create_subscription(JointState, '/window/joint_states', got.append,
                                   QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE),
                                   raw=True)
    progress = node.create_publisher(UInt64, '/bag_player/consumed', 10)
    player = subprocess.Popen(cobot_calib('replay', str(tmp_path / 'b'), '--rate', 'max',
                                          '--window', '10', '--wait-subscribers', '30'),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=bag_domain[1])
    try:
        deadline = time.monotonic() + 120
        while player.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.01)        # one message per round at most
            progress.publish(UInt64(data=len(got)))
            time.sleep(0.002)                           # busy elsewhere between rounds
        out, _ = player.communicate(timeout=TIMEOUT)
    finally:
        if player.poll() is None:
            player.kill()
        node.destroy_subscription(sub)
        node.destroy_publisher(progress)
    assert player.returncode == 0, out
    assert f'published {count} messages' in out, out
    assert ', 0 never counted' in out, out
    with open_bag(tmp_path / 'b') as bag:
        recorded = [m.rawdata for m in bag.messages()]
    assert got[-count:] == recorded                     # the first may have come twice
