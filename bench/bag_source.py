"""The recording bench's source: 1 kHz JointState and 10 Hz 752x480 mono8 Image, reliable.

Run as its own process by bench_bag. Waits until both topics have a matched subscriber, prints
``start``, publishes for ``--seconds`` (raw CDR built once; each message numbered in its header
stamp: joint_states seq -> BASE_S + seq ms, images seq -> BASE_S + seq * 100 ms), prints
``end <joint_states> <images> <seconds>`` (counts published), waits for the subscribers'
acknowledgements and prints ``done``.
"""
from __future__ import annotations

import argparse
import struct
import sys
import time

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState

from cobot_calib_ros.bags import interfaces

BASE_S = 1_000_000
STAMP = struct.Struct('<iI')        # header.stamp right after the 4-byte CDR header
WIDTH, HEIGHT = 752, 480


def templates() -> tuple[bytearray, bytearray]:
    """CDR of one JointState (7 joints) and one mono8 Image, padding zeroed."""
    store = interfaces.typestore()
    t = store.types
    header = t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](sec=0, nanosec=0),
                                      frame_id='base')
    js = t['sensor_msgs/msg/JointState'](
        header=header, name=[f'right_j{k}' for k in range(7)],
        position=np.linspace(-1, 1, 7), velocity=np.zeros(7), effort=np.zeros(7))
    camera = t['std_msgs/msg/Header'](stamp=header.stamp, frame_id='camera')
    image = t['sensor_msgs/msg/Image'](
        header=camera, height=HEIGHT, width=WIDTH, encoding='mono8', is_bigendian=0,
        step=WIDTH, data=(np.arange(WIDTH * HEIGHT) % 251).astype(np.uint8))
    return (bytearray(store.serialize_cdr(js, 'sensor_msgs/msg/JointState')),
            bytearray(store.serialize_cdr(image, 'sensor_msgs/msg/Image')))


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--hz', type=float, default=1000.0)
    parser.add_argument('--image-every', type=int, default=100, help='joint_states per image')
    args = parser.parse_args()
    rclpy.init()
    node = rclpy.create_node('bench_bag_source', start_parameter_services=False)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    js_pub = node.create_publisher(JointState, 'joint_states', reliable)
    image_pub = node.create_publisher(Image, 'camera/image_raw',
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    js, image = templates()
    deadline = time.monotonic() + 120.0
    while (js_pub.get_subscription_count() < 1 or image_pub.get_subscription_count() < 1) \
            and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)                          # let the matches settle on both sides
    print('start', flush=True)
    total = int(args.seconds * args.hz)
    period = 1.0 / args.hz
    images = 0
    start = time.monotonic()
    for seq in range(total):
        STAMP.pack_into(js, 4, BASE_S + seq // 1000, (seq % 1000) * 1_000_000)
        js_pub.publish(bytes(js))
        if seq % args.image_every == 0:
            STAMP.pack_into(image, 4, BASE_S + images // 10, (images % 10) * 100_000_000)
            image_pub.publish(bytes(image))
            images += 1
        delay = start + (seq + 1) * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    print(f'end {total} {images} {time.monotonic() - start:.3f}', flush=True)
    for pub in (js_pub, image_pub):
        pub.wait_for_all_acked(Duration(seconds=10))
    print('done', flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
