"""sensor_msgs/Image and CameraInfo <-> numpy and core.landmarks.camera.CameraModel (cf.
cv_bridge, which is not on PyPI).

Encodings: mono8, bgr8 and rgb8 (8-bit, rows of ``step`` bytes, padding allowed). A message
that does not fit raises ImageMessageError with a ``reason`` ('empty_image',
'unsupported_encoding', 'corrupt_image') for the receiver's counters.
"""
from __future__ import annotations

import array

from builtin_interfaces.msg import Time
import cv2
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import CameraInfo, Image

from cobot_calib_ros.core.landmarks.camera import CameraModel

CHANNELS = {'mono8': 1, 'bgr8': 3, 'rgb8': 3}


class ImageMessageError(ValueError):
    """An Image message that cannot be read; ``reason`` names the kind of problem."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def image_to_gray(msg: Image) -> NDArray[np.uint8]:
    """(height, width) mono8 of a mono8 (a view of the message data), bgr8 or rgb8 message."""
    channels = CHANNELS.get(msg.encoding)
    if channels is None:
        raise ImageMessageError('unsupported_encoding', f'encoding {msg.encoding!r} is not '
                                f'supported; use one of {", ".join(CHANNELS)}')
    h, w, step = msg.height, msg.width, msg.step
    if h == 0 or w == 0:
        raise ImageMessageError('empty_image', f'the image is {w}x{h} px')
    if step < w * channels or len(msg.data) != step * h:
        raise ImageMessageError('corrupt_image', f'{len(msg.data)} bytes of data for a {w}x{h} '
                                f'{msg.encoding} image with rows of {step} bytes (expected '
                                f'height x step = {h * step}, step >= {w * channels})')
    rows = np.frombuffer(msg.data, dtype=np.uint8).reshape(h, step)
    pixels = rows[:, :w * channels].reshape(h, w, channels)
    if channels == 1:
        return pixels[:, :, 0]
    return cv2.cvtColor(pixels, cv2.COLOR_BGR2GRAY if msg.encoding == 'bgr8'
                        else cv2.COLOR_RGB2GRAY)


def gray_to_image(gray: NDArray[np.uint8], frame_id: str, stamp: Time | None = None) -> Image:
    """A mono8 Image message of a (height, width) uint8 array."""
    gray = np.ascontiguousarray(gray, dtype=np.uint8)
    msg = Image(height=gray.shape[0], width=gray.shape[1], encoding='mono8', is_bigendian=0,
                step=gray.shape[1])
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    data = array.array('B')
    data.frombytes(gray.data)           # a copy without a per-element check
    msg.data = data
    return msg


def camera_info_to_model(msg: CameraInfo) -> CameraModel:
    """CameraModel (K, D, size) of a CameraInfo; ValueError names what does not fit."""
    return CameraModel(msg.width or None, msg.height or None,
                       np.asarray(msg.k, dtype=float).reshape(3, 3),
                       np.asarray(msg.d, dtype=float), msg.distortion_model or 'plumb_bob',
                       msg.header.frame_id)


def model_to_camera_info(camera: CameraModel, frame_id: str) -> CameraInfo:
    """CameraInfo of a raw (unrectified) camera: K, D, R = I and P = [K | 0]."""
    msg = CameraInfo(width=camera.width or 0, height=camera.height or 0,
                     distortion_model=camera.distortion_model)
    msg.header.frame_id = frame_id
    msg.k = camera.K.ravel().tolist()
    msg.d = camera.D.tolist()
    msg.r = np.eye(3).ravel().tolist()
    msg.p = np.hstack([camera.K, np.zeros((3, 1))]).ravel().tolist()
    return msg
