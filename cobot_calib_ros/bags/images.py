"""The images of a bag's sensor_msgs/Image topic, as mono8 arrays named by their stamp."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.reader import open_bag

DEFAULT_TOPIC = '/wrist_camera/image_raw'


def bag_images(path: str | Path, topic: str = DEFAULT_TOPIC, every: int = 1
               ) -> Iterator[tuple[str, NDArray[np.uint8] | None]]:
    """(header stamp [ns] as text, mono8 image) of every ``every``-th image on ``topic``; the
    image is None when its encoding or data cannot be used. BagError when the bag has no such
    topic (it names the bag's topics) or it holds no sensor_msgs/msg/Image."""
    from cobot_calib_ros.ros.images import image_to_gray, ImageMessageError
    from cobot_calib_ros.ros.time import stamp_to_ns
    with open_bag(path) as bag:
        name = bag.select([topic])[0]
        msgtype = bag.topics[name].type
        if msgtype != 'sensor_msgs/msg/Image':
            raise BagError(f'{path}: {name} holds {msgtype}, not sensor_msgs/msg/Image; give '
                           'the camera\'s image topic with --topic')
        for i, message in enumerate(bag.messages([name])):
            if i % every:
                continue
            msg = bag.deserialize(message.rawdata, message.msgtype)
            stamp = stamp_to_ns(msg.header.stamp)
            try:
                yield str(stamp), np.ascontiguousarray(image_to_gray(msg))
            except ImageMessageError:
                yield str(stamp), None
