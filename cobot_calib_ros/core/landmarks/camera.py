"""Camera intrinsics for fiducial poses: K and D of the raw image, and the files they come in.

Poses are solved on the raw image with ``camera_matrix`` (K) and ``distortion_coefficients`` (D);
``projection_matrix`` (P) describes the *rectified* image and is not used here.

OpenCV is imported where it is used: every node reads its cell's camera at start, and most
never project a point (cv2's import is ~60 ms of CPU per process).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure

# distortion_model (sensor_msgs/CameraInfo names) -> allowed numbers of coefficients
DISTORTION_MODELS = {
    'plumb_bob': (0, 4, 5),            # k1 k2 p1 p2 [k3], OpenCV's default model
    'rational_polynomial': (0, 8),     # k1 k2 p1 p2 k3 k4 k5 k6
    'equidistant': (0, 4),             # fisheye k1 k2 k3 k4 (cv2.fisheye)
}

# undistortPoints' default (5 iterations) leaves ~0.1 px on strong lenses
_UNDISTORT_ITERATIONS = 100
_UNDISTORT_EPS = 1e-12


class CameraInfoError(ValueError):
    """A camera-info file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole camera of the raw image: K (3, 3) [px], D (k,), image size [px] (None: unknown).

    ``distortion_model`` is a sensor_msgs/CameraInfo name: 'plumb_bob' (also 4 coefficients),
    'rational_polynomial' or 'equidistant' (fisheye). An empty D means no distortion.
    """

    width: int | None
    height: int | None
    K: NDArray[np.float64]
    D: NDArray[np.float64] = field(default_factory=lambda: np.zeros(5))
    distortion_model: str = 'plumb_bob'
    name: str = ''

    def __post_init__(self):
        K = np.asarray(self.K, dtype=float)
        D = np.asarray(self.D, dtype=float).ravel()
        if K.shape != (3, 3):
            raise ValueError(f'camera matrix K must be 3x3, got shape {K.shape}')
        if not np.all(np.isfinite(K)) or not np.all(np.isfinite(D)):
            raise ValueError('camera matrix K and distortion D must be finite')
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
            raise ValueError(f'camera matrix K is not a pinhole matrix [[fx 0 cx] [0 fy cy] '
                             f'[0 0 1]] with fx, fy > 0: {K.tolist()}')
        model = self.distortion_model
        if model not in DISTORTION_MODELS:
            raise ValueError(f'distortion_model {model!r} is not supported; use one of '
                             f'{", ".join(DISTORTION_MODELS)}')
        if len(D) not in DISTORTION_MODELS[model]:
            raise ValueError(f'distortion_model {model!r} takes '
                             f'{" or ".join(map(str, DISTORTION_MODELS[model][1:]))} '
                             f'coefficients, got {len(D)}')
        if len(D) == 0:
            D = np.zeros(4 if model == 'equidistant' else 5)
        for name in ('width', 'height'):
            value = getattr(self, name)
            if value is not None and (int(value) != value or value <= 0):
                raise ValueError(f'image {name} must be a positive integer, got {value!r}')
            object.__setattr__(self, name, None if value is None else int(value))
        K.setflags(write=False)
        D.setflags(write=False)
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'D', D)

    @property
    def is_fisheye(self) -> bool:
        return self.distortion_model == 'equidistant'

    def size_problem(self, image_shape: tuple[int, ...]) -> Failure | None:
        """None if the intrinsics fit an image of this (rows, cols[, channels]) shape, else an
        INVALID_INPUT Failure saying why not."""
        if self.width is None or self.height is None:
            return None
        h, w = image_shape[:2]
        if (w, h) != (self.width, self.height):
            return Failure(ErrorCode.INVALID_INPUT, f'the image is {w}x{h} px but the camera '
                           f'info is for {self.width}x{self.height} px')
        return None

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.D != 0.0))

    def undistort_pixels(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Raw-image pixels (N, 2) -> the same rays in the distortion-free image with K."""
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if not self.has_distortion:
            return pts.reshape(-1, 2).copy()
        import cv2
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _UNDISTORT_ITERATIONS,
                    _UNDISTORT_EPS)
        if self.is_fisheye:
            out = cv2.fisheye.undistortPoints(pts, self.K, self.D, P=self.K, criteria=criteria)
        else:
            out = cv2.undistortPoints(pts, self.K, self.D, P=self.K, criteria=criteria)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def distort_pixels(self, pixels: ArrayLike) -> NDArray[np.float64]:
        """Inverse of undistort_pixels: distortion-free pixels (N, 2) -> raw-image pixels."""
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion:
            return pts.copy()
        rays = np.column_stack([pts, np.ones(len(pts))]) @ np.linalg.inv(self.K).T
        return self.project(rays, np.zeros(3), np.zeros(3))

    def pnp_inputs(self, pixels: ArrayLike):
        """(points (N, 1, 2), K, D) to give cv2.solvePnP / projectPoints for raw pixels.

        OpenCV's pinhole functions take plumb_bob and rational_polynomial D directly; a fisheye
        image's points are undistorted into the pinhole image with the same K first (D = 0).
        """
        if self.is_fisheye:
            return self.undistort_pixels(pixels).reshape(-1, 1, 2), self.K, np.zeros(5)
        return np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2), self.K, self.D

    def project(self, points: ArrayLike, rvec: ArrayLike, tvec: ArrayLike) -> NDArray[np.float64]:
        """Raw-image pixels (N, 2) of (N, 3) points given in a frame posed at (rvec, tvec)."""
        obj = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        rvec = np.ascontiguousarray(rvec, dtype=np.float64).reshape(3, 1)
        tvec = np.ascontiguousarray(tvec, dtype=np.float64).reshape(3, 1)
        import cv2
        if self.is_fisheye:
            px, _ = cv2.fisheye.projectPoints(obj, rvec, tvec, self.K, self.D)
        else:
            px, _ = cv2.projectPoints(obj, rvec, tvec, self.K, self.D)
        return px.reshape(-1, 2)


def parse_camera_info(text: str, source: str | Path) -> CameraModel:
    """CameraModel from the text of a camera-info file (``source`` names it in messages;
    loaders.load_camera_info_yaml reads the file); CameraInfoError names the key.

    Reads the ROS camera_calibration YAML (image_width, image_height, camera_name,
    camera_matrix {rows, cols, data}, distortion_model, distortion_coefficients, ...), a
    sensor_msgs/CameraInfo as `ros2 topic echo --once` prints it (width, height, k, d,
    distortion_model), and OpenCV FileStorage YAML (``%YAML:1.0``, ``!!opencv-matrix``
    camera_matrix and distortion_coefficients, optional image_width / image_height).
    """
    if text.lstrip().startswith('%YAML') or '!!opencv-matrix' in text:
        return _from_opencv_storage(source, text)
    return _from_ros_yaml(source, text)


def camera_info_yaml(camera: CameraModel) -> str:
    """The ROS camera_info YAML of ``camera`` as camera_calibration writes it and
    camera_info_manager reads it (parse_camera_info reads it back): image size, camera_name,
    camera_matrix K, distortion_model and distortion_coefficients D, rectification_matrix
    R = I and projection_matrix P = [K | 0] (a raw, unrectified camera)."""
    if camera.width is None or camera.height is None:
        raise ValueError('a camera_info file needs the image size')

    def matrix(key: str, values: NDArray[np.float64], rows: int, cols: int) -> str:
        data = ', '.join(repr(float(v)) for v in np.asarray(values, dtype=float).ravel())
        return f'{key}:\n  rows: {rows}\n  cols: {cols}\n  data: [{data}]\n'

    D = camera.D
    return (f'image_width: {camera.width}\n'
            f'image_height: {camera.height}\n'
            f'camera_name: {_yaml_scalar(camera.name or "camera")}\n'
            + matrix('camera_matrix', camera.K, 3, 3)
            + f'distortion_model: {camera.distortion_model}\n'
            + matrix('distortion_coefficients', D, 1, len(D))
            + matrix('rectification_matrix', np.eye(3), 3, 3)
            + matrix('projection_matrix', np.column_stack([camera.K, np.zeros(3)]), 3, 4))


def _yaml_scalar(text: str) -> str:
    """``text`` bare when YAML reads it back as that string, else double-quoted."""
    import json
    import re
    return text if re.fullmatch(r'[A-Za-z_][A-Za-z0-9_./-]*', text) and text.lower() not in (
        'true', 'false', 'yes', 'no', 'on', 'off', 'null') else json.dumps(text)


def _from_ros_yaml(path: str | Path, text: str) -> CameraModel:
    import yaml
    try:
        docs = [d for d in yaml.safe_load_all(text) if d is not None]
    except yaml.YAMLError as e:
        raise CameraInfoError(f'{path}: not valid YAML: {" ".join(str(e).split())}') from None
    data = docs[0] if docs else None
    if not isinstance(data, dict):
        raise CameraInfoError(f'{path}: expected a mapping with camera_matrix (ROS camera '
                              f'info YAML) or k (CameraInfo message), got {type(data).__name__}')

    def matrix(key: str, rows: int | None, cols: int | None) -> NDArray[np.float64]:
        node = data[key]
        if isinstance(node, dict):
            missing = [k for k in ('rows', 'cols', 'data') if k not in node]
            if missing:
                raise CameraInfoError(f'{path}: {key} lacks {", ".join(missing)}')
            r, c, values = node['rows'], node['cols'], node['data']
        else:
            r, c, values = rows, cols, node
        try:
            arr = np.asarray(values if values is not None else [], dtype=float)
        except (TypeError, ValueError):
            raise CameraInfoError(f'{path}: {key} data is not a list of numbers') from None
        if arr.ndim != 1:
            raise CameraInfoError(f'{path}: {key} data is not a flat list of numbers')
        if r is not None and c is not None:
            if len(arr) != r * c:
                raise CameraInfoError(f'{path}: {key} has {len(arr)} values, expected rows x '
                                      f'cols = {r}x{c} = {r * c}')
            if (rows, cols) != (None, None) and (r, c) != (rows, cols):
                raise CameraInfoError(f'{path}: {key} is {r}x{c}, expected {rows}x{cols}')
        return arr

    if 'camera_matrix' in data:           # camera_calibration's file
        keys = dict(K='camera_matrix', D='distortion_coefficients', width='image_width',
                    height='image_height', name='camera_name')
    elif 'k' in data or 'K' in data:      # a CameraInfo message (ROS 2 lower case, ROS 1 upper)
        upper = 'K' in data
        keys = dict(K='K' if upper else 'k', D='D' if upper else 'd', width='width',
                    height='height', name='')
    else:
        raise CameraInfoError(f'{path}: no camera_matrix key (nor k of a CameraInfo message); '
                              f'keys are {", ".join(map(str, data))}')
    K = matrix(keys['K'], 3, 3).reshape(3, 3)
    D = matrix(keys['D'], None, None) if data.get(keys['D']) is not None else np.zeros(0)
    model = data.get('distortion_model') or 'plumb_bob'
    sizes = {}
    for k in ('width', 'height'):
        value = data.get(keys[k])
        sizes[k] = None if value in (None, 0) else value
    try:
        return CameraModel(sizes['width'], sizes['height'], K, D, str(model),
                           str(data.get(keys['name']) or '') if keys['name'] else '')
    except ValueError as e:
        raise CameraInfoError(f'{path}: {e}') from None


def _from_opencv_storage(path: str | Path, text: str) -> CameraModel:
    import cv2
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as e:
        raise CameraInfoError(f'{path}: not a readable OpenCV FileStorage file: '
                              f'{e.err or e}') from None
    if not fs.isOpened():
        raise CameraInfoError(f'{path}: not a readable OpenCV FileStorage file')
    try:
        def mat(key: str, required: bool) -> NDArray[np.float64] | None:
            node = fs.getNode(key)
            if node.empty():
                if required:
                    raise CameraInfoError(f'{path}: no {key} (an !!opencv-matrix)')
                return None
            m = node.mat()
            if m is None:
                raise CameraInfoError(f'{path}: {key} is not an !!opencv-matrix')
            return np.asarray(m, dtype=float)

        K = mat('camera_matrix', True)
        if K.shape != (3, 3):
            raise CameraInfoError(f'{path}: camera_matrix is {K.shape[0]}x{K.shape[1]}, '
                                  f'expected 3x3')
        D = mat('distortion_coefficients', False)
        if D is not None and 1 not in D.shape:
            raise CameraInfoError(f'{path}: distortion_coefficients is {D.shape[0]}x'
                                  f'{D.shape[1]}, expected one row or one column')
        D = np.zeros(0) if D is None else D.ravel()
        sizes = {}
        for key in ('image_width', 'image_height'):
            node = fs.getNode(key)
            sizes[key] = None if node.empty() or not node.isInt() and not node.isReal() \
                else int(node.real())
        fisheye = not fs.getNode('fisheye_model').empty() and fs.getNode('fisheye_model').real()
        model = 'equidistant' if fisheye else ('rational_polynomial' if len(D) == 8
                                               else 'plumb_bob')
        if model == 'plumb_bob' and len(D) not in DISTORTION_MODELS['plumb_bob']:
            raise CameraInfoError(f'{path}: distortion_coefficients has {len(D)} values; '
                                  f'supported are 4, 5 (plumb_bob) and 8 (rational_polynomial)')
        try:
            return CameraModel(sizes['image_width'], sizes['image_height'], K, D, model)
        except ValueError as e:
            raise CameraInfoError(f'{path}: {e}') from None
    finally:
        fs.release()
