"""landmark_detector: fiducial markers and a ChArUco board in the wrist camera's images, posed.

Subscribes ``wrist_camera/image_raw`` (mono8, bgr8 or rgb8) and ``wrist_camera/camera_info``
(K and D of the raw image), sensor-data QoS; publishes ``landmarks``
(cobot_calib_msgs/Landmarks: each marker's and the board's T_optical_target with covariance,
reprojection error, IPPE ambiguity ratio and corners), stamped with the image's stamp, for
every image it processes (empty when it found nothing).

It rests while nobody subscribes to ``landmarks``: then it does not subscribe to the images
either (the publisher's matched event says when that changes; a look every DEMAND_PERIOD backs
it up), so a camera driver that publishes only to subscribers (mock_camera) rests too; an idle
suite cost 14 % of a core in rendering and detecting images nobody used (issue 23). At rest
its threads wake about once a second (a 10 Hz look and 10 Hz worker polls were 2.6 % of a
core of an idle suite, issue 38).

Detection (core.landmarks) runs on two worker threads, so the executor keeps taking images: a
queue of up to FRAME_QUEUE_DEPTH images waits for them, and when it is full its oldest image is
dropped (counted as ``dropped``). The first thread runs OpenCV's search on the oldest (the GIL
released), then hands it to the second, which refines the corners, solves the poses and
publishes, while the first searches the next image (one image in each stage, nothing dropped
between them; ``landmarks`` keep the images' order).
Images are checked on arrival: an empty or corrupt one (data length against step x height), an
unsupported encoding, or one before any camera_info is counted under ``failed_<reason>``, logged
(throttled) and skipped; the node never stops for an image.

K and D: the cell camera's active intrinsics record in data_dir (``cobot-calib intrinsics``)
when there is one for images of its size (parameter intrinsics: 'active', the default), else
camera_info's ('camera_info': always).

Parameters (read at start-up): cell_file (its ``landmarks:`` give the defaults), dictionary,
marker_length [m], board (ChArUco spec; ``none`` for no board), refine (single markers' corner
refinement; not ``apriltag``: ~2 fps; the board's markers take ``subpix``, see
BOARD_MARKER_REFINE), opencv_threads (cv2.setNumThreads; see DEFAULT_OPENCV_THREADS).
``dictionary: none`` searches no single markers. A parameter that cannot
be used (an unknown dictionary, ...) leaves the node running with /diagnostics at ERROR and the
reason (WARN when nothing was configured: a cell without landmarks), and every image counted as
``failed_configuration``. min_marker_fraction [1]: the smallest single marker searched, as a
fraction of the image's larger side (DEFAULT_MIN_MARKER_FRACTION; 0 = every size).

/diagnostics (1 Hz): ``frames_in``, ``frames_out``, ``dropped`` (the node's queue),
``lost_in_transport`` (DDS's message_lost events of the image subscription), ``failures`` with
``failed_<reason>``, ``detect_ms_mean`` over the last second (search + refinement, poses and
message of one image; the two stages overlap, so the node keeps up with more than
1000 / detect_ms images per second), the configuration, and
``last_failure``. WARN on new failures or no image for NO_IMAGE_TIMEOUT; ERROR on a bad
configuration.
"""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
import math
import sys
import threading
import time

from cobot_calib_msgs.msg import Landmark, Landmarks
import cv2
from geometry_msgs.msg import Point, Pose, PoseWithCovariance, Quaternion
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import (PublisherEventCallbacks, QoSMessageLostInfo,
                                 SubscriptionEventCallbacks)
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile
from sensor_msgs.msg import CameraInfo, Image

from cobot_calib_ros import paths
from cobot_calib_ros.core.cell import CellFileError
from cobot_calib_ros.core.frames import Rotation
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.detect import (DEFAULT_REFINE, REFINE_METHODS,
                                                   search_parameters)
from cobot_calib_ros.core.landmarks.pipeline import Pipeline
from cobot_calib_ros.core.landmarks.pose import PoseEstimate
from cobot_calib_ros.core.landmarks.targets import BoardSpec, canonical_dictionary_name
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, ERROR, OK, WARN
from cobot_calib_ros.ros.images import camera_info_to_model, image_to_gray, ImageMessageError
from cobot_calib_ros.ros.params import read_once

NO_IMAGE_TIMEOUT = 2.0      # [s] of wall time without an image: /diagnostics warns
# [s] between looks at whether anyone subscribes to landmarks, beside the matched event
DEMAND_PERIOD = 2.0
INTRINSICS_CHECK_PERIOD = 2.0   # [s] between looks at which intrinsics are active
LIVE_REFINE = tuple(r for r in REFINE_METHODS if r != 'apriltag')   # apriltag: ~2 fps
# Best effort, as cameras publish; the reader keeps IMAGE_QUEUE_DEPTH images so that a late
# executor round (the GIL held by the poses thread, another process on the core) does not lose
# frames in DDS: with depth 1, 17-37 % of the frames sent at 100 Hz at 1280 x 800 were replaced in
# the reader's queue before the executor took them; with 5, 0-0.6 % at load 11-17, but at load
# 11-20 a 30 Hz reader with depth 5 still lost 7-26 % of 1280 x 800 frames that way (none with
# 50; message_lost 0: not in transport; 2026-11-28). One second at 30 fps: the executor only
# moves each image to FrameQueue, so the reader's queue fills only while the executor is
# starved, and adds no latency while it is not.
IMAGE_QUEUE_DEPTH = 30
# The node's own queue between the executor and the search: a burst of late work (the machine
# busy for a moment) waits in it instead of being lost; beyond FRAME_QUEUE_DEPTH images (the
# node slower than the camera for long) the oldest are dropped and counted, so the landmarks
# stay at most this many images behind.
FRAME_QUEUE_DEPTH = 8
LATEST_INFO_QOS = QoSProfile(depth=1, reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
IMAGE_QOS = QoSProfile(depth=IMAGE_QUEUE_DEPTH,
                       reliability=qos_profile_sensor_data.reliability,
                       durability=qos_profile_sensor_data.durability)
# Python hands the GIL to a waiting thread only after it has been held this long (default 5 ms).
# The executor thread needs the GIL several times per image while the poses thread holds it
# for ~4-6 ms of numpy per 1280 x 800 image: at 5 ms the executor fell behind 100 images/s.
GIL_SWITCH_INTERVAL = 0.0005    # [s] (sys.setswitchinterval, this process)
NONE = 'none'
# The board's markers only seed its chessboard corners (cornerSubPix, then saddle points): on 12
# renderings at 752x480 and 1280x800 the board poses were the same to 1e-4 mm with 'edges',
# 'subpix' or 'none' marker corners, and 'edges' took twice as long (16 against 7 ms).
BOARD_MARKER_REFINE = 'subpix'
# OpenCV's own threads (0 = one per core). With the two-stage pipeline the stages already use
# both cores of this machine; measured 2026-11-23 (2 cores, 1280x800): in one process the
# pipeline ran 114-119 images/s of markers with 1 thread against 77-111 with 2; through the node
# at load 11-13 the board held 29-29.4 of 30 fps with 1 thread against 16.6-18.6 with 2 (markers
# 29-44 against 34-59: not settled at that load).
DEFAULT_OPENCV_THREADS = 1
# > 0: single markers are searched with OpenCV's ArUco 3 method (the candidate search on the
# image scaled down so that the smallest marker asked for still has a few pixels a module, the
# corners on the full image). At 1280x800 (bench_detector's markers, 1 thread) 0.02 took 2.4 ms
# against 6.8 for the full search, the same 4 markers; but on the sample bag
# landmark_multi_close (752x480) it changed the replayed frame by 0.40 mm / 2.9 mrad: the full
# search stays the default.
DEFAULT_MIN_MARKER_FRACTION = 0.0


class NotConfigured(ValueError):
    """Nothing to detect was configured (a cell without landmarks, no parameters)."""


@dataclass(frozen=True)
class Config:
    dictionary: str | None         # canonical name; None: no single markers
    marker_length: float           # [m]
    board: BoardSpec | None
    refine: str

    def describe(self) -> str:
        markers = (f'{self.dictionary} markers of {self.marker_length * 1e3:g} mm (refine '
                   f'{self.refine})' if self.dictionary else 'no single markers')
        return f'{markers}, board {self.board or NONE}'


def configure(cell_file: str, dictionary: str, marker_length: float, board: str,
              refine: str) -> Config:
    """The detector's configuration from its parameters, the cell's landmarks as defaults;
    ValueError says what is wrong."""
    marks = None
    if not (dictionary and marker_length > 0 and board):
        try:
            marks = load_cell(paths.cell_file(cell_file)).landmarks
        except CellFileError as e:
            raise ValueError(f'cell_file: {e}') from None
    dictionary = dictionary or (marks.dictionary if marks else '')
    if not dictionary:
        raise NotConfigured('no marker dictionary: set the dictionary parameter (or "none") '
                            'or give the cell file a landmarks: section')
    use_markers = dictionary.lower() != NONE
    name = canonical_dictionary_name(dictionary) if use_markers else None
    length = marker_length or (marks.marker_length if marks else 0.0)
    if use_markers and not length > 0:
        raise ValueError('no marker length: set marker_length [m] or give the cell file a '
                         'landmarks: section')
    board = board or (marks.board if marks else '') or NONE
    spec = None if board.lower() == NONE else BoardSpec.parse(board)
    if refine not in LIVE_REFINE:
        raise ValueError(f'refine {refine!r}: use one of {", ".join(LIVE_REFINE)} (apriltag '
                         'refinement runs at ~2 fps, too slow for a live camera)')
    if name is None and spec is None:
        raise ValueError('nothing to detect: dictionary and board are both "none"')
    return Config(name, float(length), spec, refine)


class _Stage:
    """A hand-over between the pipeline's threads whose ``take`` a ``close`` ends at once."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._closed = False

    def close(self) -> None:
        """A ``take`` waiting now, or later, returns at once."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class FrameQueue(_Stage):
    """Images between the executor and the search, oldest first; a full queue drops its oldest
    (counted in ``dropped``)."""

    def __init__(self, depth: int = FRAME_QUEUE_DEPTH) -> None:
        super().__init__()
        self._items: deque = deque()
        self._depth = depth
        self.dropped = 0

    def put(self, item) -> None:
        with self._cond:
            if len(self._items) >= self._depth:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def take(self, timeout: float):
        with self._cond:
            if not self._items and not self._closed:
                self._cond.wait(timeout)
            return self._items.popleft() if self._items else None


class Handoff(_Stage):
    """One-slot hand-over between the pipeline's threads that loses nothing: ``put`` waits
    while the slot is full (the next stage is busy), up to ``timeout``."""

    def __init__(self) -> None:
        super().__init__()
        self._item = None

    def put(self, item, timeout: float) -> bool:
        with self._cond:
            if self._item is not None:
                self._cond.wait_for(lambda: self._item is None, timeout)
            if self._item is not None:
                return False
            self._item = item
            self._cond.notify_all()
            return True

    def take(self, timeout: float):
        with self._cond:
            if self._item is None and not self._closed:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            self._cond.notify_all()
            return item


def landmark_message(kind: str, target_id: int, pose: PoseEstimate, corners: np.ndarray,
                     corner_ids: np.ndarray | None = None,
                     quaternion: np.ndarray | None = None) -> Landmark:
    """``quaternion`` (x, y, z, w): the pose's rotation when already converted (detect
    converts all landmarks' rotations in one call: 0.12 ms each one by one)."""
    T = pose.T_optical_target
    if quaternion is None:
        quaternion = Rotation.from_matrix(T[:3, :3]).as_quat()
    x, y, z = (float(v) for v in T[:3, 3])
    qx, qy, qz, qw = (float(v) for v in quaternion)
    msg = Landmark(id=int(target_id), kind=kind, reprojection_error=float(pose.rms_px))
    msg.pose = PoseWithCovariance(pose=Pose(position=Point(x=x, y=y, z=z),
                                            orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)))
    msg.pose.covariance = np.asarray(pose.covariance, dtype=float).ravel()
    ratio = pose.ambiguity_ratio
    msg.ambiguity_ratio = math.nan if ratio is None else float(ratio)
    msg.corners = np.asarray(corners, dtype=float).ravel().tolist()
    if corner_ids is not None:
        msg.corner_ids = np.asarray(corner_ids, dtype=np.int32).ravel().tolist()
    return msg


class Detector:
    """The configured search (core.landmarks.pipeline) for the node's pipeline: ``find``
    (OpenCV's searches, the GIL released) and ``finish`` (refinement, poses, messages).
    ``min_marker_fraction``: see core.landmarks.detect.search_parameters."""

    def __init__(self, config: Config, min_marker_fraction: float = 0.0) -> None:
        self.config = config
        self._pipeline = Pipeline(
            config.dictionary, config.board, marker_length=config.marker_length,
            refine=config.refine,
            board_refine=NONE if config.refine == NONE else BOARD_MARKER_REFINE,
            params=search_parameters(min_marker_fraction))

    def find(self, gray: np.ndarray) -> tuple:
        return self._pipeline.find(gray)

    def finish(self, found: tuple, camera: CameraModel) -> list[Landmark]:
        """Every marker and the board of ``find``'s result, posed."""
        found = self._pipeline.finish(found, camera)
        posed = [(Landmark.KIND_MARKER, marker.id, pose, marker.corners, None)
                 for marker, pose in found.markers if pose is not None]
        if found.board_pose is not None:
            posed.append((Landmark.KIND_BOARD, self.config.board.first_id, found.board_pose,
                          found.board.charuco_corners, found.board.charuco_ids))
        if not posed:
            return []
        quaternions = Rotation.from_matrix(
            np.stack([p[2].T_optical_target[:3, :3] for p in posed])).as_quat()
        return [landmark_message(kind, i, pose, corners, ids, q)
                for (kind, i, pose, corners, ids), q in zip(posed, quaternions)]


def detect(gray: np.ndarray, camera: CameraModel, config: Config) -> list[Landmark]:
    """Every marker and the board found in one mono8 image, posed (core.landmarks)."""
    detector = Detector(config)
    return detector.finish(detector.find(gray), camera)


class LandmarkDetector(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('landmark_detector', **kwargs)
        self._config, self._config_error, self._config_level = self._configure()
        threads = read_once(self, 'opencv_threads', DEFAULT_OPENCV_THREADS,
                            "OpenCV's threads (cv2.setNumThreads, for the process); 0 = "
                            "OpenCV's default (one per core)", 0, 64)
        if threads:
            cv2.setNumThreads(threads)
        min_fraction = read_once(
            self, 'min_marker_fraction', DEFAULT_MIN_MARKER_FRACTION,
            "Smallest single marker searched, as a fraction of the image's larger side [1] "
            "(OpenCV's ArUco 3 search, ~3x faster at 1280x800); 0 = every size, at full "
            'resolution', 0.0, 0.5)
        self._detector = None
        if self._config:
            try:
                self._detector = Detector(self._config, min_fraction)
            except (ValueError, cv2.error) as e:    # never seen: configure checked the names
                self._config_error, self._config_level = \
                    f'landmark_detector cannot detect: {e}', ERROR
        self._camera: CameraModel | None = None
        self._camera_key = None
        self._active_intrinsics = self._read_active_intrinsics()
        self._lock = threading.Lock()
        self._counts = Counter()            # frames_in, frames_out, failed_<reason>
        self._last_failure = ''
        self._failures_reported = 0
        self._detect_s: list[float] = []
        self._last_image = self._started = time.monotonic()
        self._queue = FrameQueue()
        self._handoff = Handoff()
        self._image_sub = None              # only while someone subscribes to landmarks
        self._pub = self.create_publisher(
            Landmarks, 'landmarks', 10,
            event_callbacks=PublisherEventCallbacks(matched=lambda _: self._follow_demand()))
        # camera_info comes with every image and rarely changes: it waits in a depth-1 queue
        # of a helper node no executor spins, and each image takes the newest (one executor
        # round per image instead of two)
        self._info_node = Node(f'_{self.get_name()}_camera_info',
                               namespace=self.get_namespace(), context=self.context,
                               start_parameter_services=False)
        self._info_sub = self._info_node.create_subscription(
            CameraInfo, 'wrist_camera/camera_info', lambda _: None, LATEST_INFO_QOS)
        self._follow_demand()
        # steady: under use_sim_time the node clock stands still until a bag plays /clock,
        # and the player waits for this node to subscribe to the images first
        self.create_timer(DEMAND_PERIOD, self._follow_demand,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._diagnostics = Diagnostics(self, hardware_id='wrist_camera', update=self._diagnose)
        self._running = True
        self._workers = [threading.Thread(target=self._search, daemon=True, name='search'),
                         threading.Thread(target=self._finish, daemon=True, name='poses')]
        for worker in self._workers:
            worker.start()
        if self._config_error:
            self.get_logger().error(self._config_error)
        else:
            self.get_logger().info(f'detecting {self._config.describe()}')

    def destroy_node(self):
        self._running = False
        self._queue.close()
        self._handoff.close()
        for worker in self._workers:
            worker.join(timeout=5.0)
        self._info_node.destroy_node()
        return super().destroy_node()

    def _read_active_intrinsics(self) -> CameraModel | None:
        """The cell camera's active intrinsics (store.rigs.active_result, the active set's
        intrinsics: cobot-calib intrinsics, camera_calibrator), which replace camera_info's K
        and D; None: camera_info's hold.
        Read at start and again every INTRINSICS_CHECK_PERIOD (:meth:`_follow_intrinsics`):
        a new calibration is used without a restart."""
        source = read_once(self, 'intrinsics', 'active',
                           "K and D of the images: 'active' (the camera's active intrinsics "
                           "record in data_dir, else camera_info's) or 'camera_info'")
        data_dir = read_once(self, 'data_dir', '', 'Results root whose active intrinsics '
                             'are used; empty = $COBOT_CALIB_DATA or ~/.ros/cobot_calib')
        self._intrinsics_id = ''
        self._intrinsics_from = None
        if source != 'active':
            return None
        try:
            cell = load_cell(paths.cell_file(self.get_parameter('cell_file').value))
        except (CellFileError, OSError, ValueError) as e:
            self.get_logger().warning(f'active intrinsics not read ({e}); camera_info holds')
            return None
        if cell.camera is None:
            return None
        self._intrinsics_from = (cell, paths.data_dir(data_dir))
        self.create_timer(INTRINSICS_CHECK_PERIOD, self._follow_intrinsics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        return self._active_intrinsics_now()

    def _active_intrinsics_now(self) -> CameraModel | None:
        from cobot_calib_ros import store
        from cobot_calib_ros.store.cells import ResultsCell
        from cobot_calib_ros.store.rigs import active_result
        cell, data_dir = self._intrinsics_from
        try:        # opened afresh: another process may have stored one since
            repo = store.open(data_dir, cell=ResultsCell.of(cell, self.get_namespace()))
            active = active_result(repo, cell, 'intrinsics')
        except Exception as e:          # noqa: BLE001 - a store that cannot be read: the topic's
            self.get_logger().warning(f'active intrinsics not read ({e}); camera_info holds',
                                      throttle_duration_sec=60.0)
            return self._active_intrinsics if self._intrinsics_id else None
        if (active.id if active else '') != self._intrinsics_id:
            self._intrinsics_id = active.id if active else ''
            if active is not None:
                self.get_logger().info(
                    f'using the active intrinsics {active.id} of {active.camera} (fx '
                    f'{active.model.K[0, 0]:.2f} px) instead of camera_info\'s')
            else:
                self.get_logger().info('no active intrinsics: camera_info\'s hold')
        return None if active is None else active.model

    def _follow_intrinsics(self) -> None:
        """A new active intrinsics calibration replaces the one in use (the next camera_info
        takes it)."""
        before = self._intrinsics_id
        model = self._active_intrinsics_now()
        if self._intrinsics_id != before:
            with self._lock:
                self._active_intrinsics, self._camera_key = model, None

    def _configure(self) -> tuple[Config | None, str, int]:
        values = (
            read_once(self, 'cell_file', paths.DEFAULT_CELL,
                      'Cell YAML whose landmarks: give the defaults: a path or a name in '
                      'config/cells'),
            read_once(self, 'dictionary', '',
                      'Marker dictionary (DICT_5X5_100, DICT_APRILTAG_36h11, ...); empty = the '
                      "cell's, none = no single markers"),
            read_once(self, 'marker_length', 0.0,
                      "Side of a single marker's black square [m]; 0 = the cell's", 0.0, 5.0),
            read_once(self, 'board', '',
                      'ChArUco board spec (charuco:squares=7x5,square=0.03,marker=0.022,'
                      "dict=DICT_4X4_50); empty = the cell's, none = no board"),
            read_once(self, 'refine', DEFAULT_REFINE,
                      f'Corner refinement: {", ".join(LIVE_REFINE)}'),
        )
        try:
            return configure(*values), '', OK
        except ValueError as e:
            return None, f'landmark_detector cannot detect: {e}', \
                WARN if isinstance(e, NotConfigured) else ERROR

    # -- executor thread ------------------------------------------------------------------
    def _follow_demand(self) -> None:
        """Take images while someone subscribes to landmarks; rest otherwise."""
        wanted = self._pub.get_subscription_count() > 0
        if wanted and self._image_sub is None:
            self._image_sub = self.create_subscription(
                Image, 'wrist_camera/image_raw', self._on_image, IMAGE_QOS,
                event_callbacks=SubscriptionEventCallbacks(message_lost=self._on_lost))
            self._last_image = time.monotonic()
        elif not wanted and self._image_sub is not None:
            self.destroy_subscription(self._image_sub)
            self._image_sub = None

    def _on_lost(self, info: QoSMessageLostInfo) -> None:
        """Images DDS reports lost on the way (e.g. fragments overwritten in a shared-memory
        segment too small for them: see config/fastdds_large_images.xml)."""
        with self._lock:
            self._counts['lost_in_transport'] += info.total_count_change

    def _on_info(self, msg: CameraInfo) -> None:
        key = (msg.width, msg.height, msg.distortion_model, msg.header.frame_id,
               tuple(msg.k), tuple(msg.d))
        if key == self._camera_key:
            return                      # a driver sends the same with every image
        try:
            camera = camera_info_to_model(msg)
        except ValueError as e:
            self._fail('bad_camera_info', f'camera_info refused: {e}')
            return
        active = self._active_intrinsics
        if active is not None and (active.width, active.height) == (camera.width,
                                                                     camera.height):
            camera = active
        with self._lock:
            self._camera, self._camera_key = camera, key

    def _take_camera_info(self) -> None:
        """The newest camera_info, if one came since the last image."""
        sub = self._info_sub
        with sub.handle:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
        if taken is not None:
            self._on_info(taken[0])

    def _on_image(self, msg: Image) -> None:
        self._last_image = time.monotonic()
        self._take_camera_info()
        with self._lock:
            self._counts['frames_in'] += 1
            camera = self._camera
        if self._config_error:
            self._fail('configuration', self._config_error)
            return
        if camera is None:
            self._fail('no_camera_info', 'no camera_info received yet on '
                       'wrist_camera/camera_info; image skipped')
            return
        try:
            gray = image_to_gray(msg)
        except ImageMessageError as e:
            self._fail(e.reason, f'image refused: {e}')
            return
        problem = camera.size_problem(gray.shape)
        if problem is not None:
            self._fail('camera_info_mismatch', f'image refused: {problem.message}')
            return
        self._queue.put((msg.header, gray, camera))

    def _fail(self, reason: str, message: str) -> None:
        with self._lock:
            self._counts[f'failed_{reason}'] += 1
            self._last_failure = message
        self.get_logger().warning(message, throttle_duration_sec=5.0)

    # -- worker threads -------------------------------------------------------------------
    # Two stages, so that OpenCV searches the next image (GIL released) while the previous one
    # is refined and posed (numpy, GIL held): at 1280x800 that ran ~20-35 % more images per
    # second than one thread doing both (measured in one process, 2 cores).
    def _search(self) -> None:
        while self._running and self.context.ok():
            item = self._queue.take(timeout=spin.IDLE_WAKE)
            if item is None:
                continue
            header, gray, camera = item
            start = time.perf_counter()
            try:
                found = self._detector.find(gray)
            except Exception as exc:  # noqa: BLE001 - a frame must never stop the detector
                self._fail('detection_error', f'detection failed: {exc!r}')
                continue
            item = (header, camera, found, time.perf_counter() - start)
            while self._running and not self._handoff.put(item, spin.WAKE_PERIOD):
                pass

    def _finish(self) -> None:
        while self._running and self.context.ok():
            item = self._handoff.take(timeout=spin.IDLE_WAKE)
            if item is None:
                continue
            header, camera, found, search_s = item
            start = time.perf_counter()
            try:
                landmarks = self._detector.finish(found, camera)
            except Exception as exc:  # noqa: BLE001 - a frame must never stop the detector
                self._fail('detection_error', f'detection failed: {exc!r}')
                continue
            msg = Landmarks(header=header, landmarks=landmarks)
            if not msg.header.frame_id:
                msg.header.frame_id = camera.name
            try:
                self._pub.publish(msg)
            except Exception:  # noqa: BLE001 - the context went down under us at shutdown
                if self.context.ok():
                    raise
                return
            with self._lock:
                self._counts['frames_out'] += 1
                self._detect_s.append(search_s + time.perf_counter() - start)

    # -- /diagnostics ---------------------------------------------------------------------
    def _diagnose(self) -> None:
        with self._lock:
            counts = dict(self._counts)
            times, self._detect_s = self._detect_s, []
            last_failure = self._last_failure
        failed = {k: v for k, v in sorted(counts.items()) if k.startswith('failed_')}
        failures = sum(failed.values())
        new_failures, self._failures_reported = failures - self._failures_reported, failures
        idle = time.monotonic() - self._last_image
        if self._config_error:
            level, message = self._config_level, self._config_error
        elif new_failures:
            level, message = WARN, f'{new_failures} images failed since the last report: ' \
                f'{last_failure}'
        elif self._image_sub is None:
            level, message = OK, 'resting: nobody subscribes to landmarks'
        elif idle > NO_IMAGE_TIMEOUT:
            level, message = WARN, (f'no image on wrist_camera/image_raw for {idle:.1f} s; is '
                                    'the camera publishing?')
        else:
            level, message = OK, 'detecting'
        self._diagnostics.set(
            level, message, frames_in=counts.get('frames_in', 0),
            frames_out=counts.get('frames_out', 0), dropped=self._queue.dropped,
            lost_in_transport=counts.get('lost_in_transport', 0),
            failures=failures, **failed,
            detect_ms_mean=f'{1e3 * float(np.mean(times)):.2f}' if times else 'nan',
            configuration=self._config.describe() if self._config else 'none',
            last_failure=last_failure)


def main(args=None) -> None:
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)
    spin.run(LandmarkDetector, args)


if __name__ == '__main__':
    main()
