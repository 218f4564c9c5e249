"""bag_recorder in this process: --all finds topics that appear later and leaves hidden ones
out; the bag is closed by destroy_node (what Ctrl-C does under ros.spin.run)."""
import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.recorder import BagRecorder
from cobot_calib_ros.ros.graph import is_hidden


def test_hidden_topics():
    assert is_hidden('/move_to/_action/feedback') and is_hidden('/_x')
    assert not is_hidden('/joint_states') and not is_hidden('/a_b/c')


def test_all_topics_late_ones_too_hidden_ones_not(bag_domain, tmp_path):
    context = Context()
    rclpy.init(context=context, domain_id=bag_domain[0])
    lines = []
    recorder = BagRecorder(str(tmp_path / 'all'), all_topics=True, report=lines.append,
                           context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(recorder)
    running = True

    def spin():
        while running:
            executor.spin_once(timeout_sec=0.05)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    node = rclpy.create_node('late_publisher', context=context)
    try:     # the recorder's first scan (in its constructor) ran before this topic existed
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        late = node.create_publisher(String, '/late_topic', reliable)
        hidden = node.create_publisher(String, '/_hidden/topic', reliable)
        deadline = time.monotonic() + 20
        while late.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert late.get_subscription_count() == 1
        for i in range(10):
            late.publish(String(data=f'late {i}'))
            hidden.publish(String(data='hidden'))
        assert late.wait_for_all_acked(Duration(seconds=10))
        assert hidden.get_subscription_count() == 0
    finally:
        running = False
        thread.join(timeout=5)
        executor.shutdown(timeout_sec=1)
        node.destroy_node()
        recorder.destroy_node()                           # closes the bag
        rclpy.try_shutdown(context=context)
    assert 'recording /late_topic (std_msgs/msg/String)' in lines
    with open_bag(tmp_path / 'all', strict=True) as bag:
        assert '/_hidden/topic' not in bag.topics
        got = [bag.deserialize(m.rawdata, m.msgtype).data for m in bag.messages(['/late_topic'])]
    assert got == [f'late {i}' for i in range(10)]


def test_a_recording_shorter_than_discovery_still_names_what_nothing_publishes(bag_domain,
                                                                                 tmp_path):
    """Issue 31.9: `record --duration 2 /unpublished` said nothing (the warning came after
    3 s of discovery); the end of the recording gives it."""
    context = Context()
    rclpy.init(context=context, domain_id=bag_domain[0])
    lines = []
    recorder = BagRecorder(str(tmp_path / 'short'), ['/nothing_publishes_31'],
                           report=lines.append, context=context)
    try:
        assert not any(line.startswith('warning:') for line in lines)
    finally:
        recorder.destroy_node()                           # ends it (as --duration does)
        rclpy.try_shutdown(context=context)
    warnings = [line for line in lines if line.startswith('warning:')]
    assert len(warnings) == 1, lines
    assert warnings[0].startswith('warning: nothing publishes /nothing_publishes_31 (after ')
    assert warnings[0].endswith(' s); recorded only if a publisher appears (see '
                                '`cobot-calib list`)')
