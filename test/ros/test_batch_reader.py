"""BatchReader: every message of a fast topic, in order, several per wake (in-process)."""
import threading

import rclpy
from rclpy.context import Context
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cobot_calib_ros.ros.batch_reader import BatchReader

MESSAGES = 400
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def test_every_message_arrives_in_order_in_batches():
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('batch_reader_test', context=context)
    batches, done = [], threading.Event()

    def on_batch(batch):
        batches.append([int(m.position[0]) for m in batch])
        if sum(map(len, batches)) >= MESSAGES:
            done.set()

    reader = BatchReader(node, 'joints', JointState, 'batch_reader_joints', RELIABLE, on_batch)
    try:
        pub = node.create_publisher(JointState, 'batch_reader_joints', RELIABLE)
        matched = threading.Event()
        while not matched.wait(0.05):               # discovery: wait for the reader
            if pub.get_subscription_count():
                matched.set()
        for i in range(MESSAGES):                   # as fast as Python publishes
            pub.publish(JointState(name=['j'], position=[float(i)]))
        assert done.wait(10.0), f'{sum(map(len, batches))} of {MESSAGES} arrived'
        assert [i for batch in batches for i in batch] == list(range(MESSAGES))
        assert len(batches) < MESSAGES / 2          # many per wake, not one each
        assert reader.node.get_name() == '_batch_reader_test_joints'
    finally:
        reader.destroy()
        node.destroy_node()
        rclpy.shutdown(context=context)
