"""The wrist camera as it really is: what it sees of the fiducials lying on the uneven table.

``Renderer`` draws mono8 images of flat textured targets (markers on paper, ChArUco boards) at
given poses T_optical_target through the camera's K and D (any CameraModel distortion model),
then light, blur and noise. ``SimCamera`` poses the cell's fiducials for it: the true chain (true kinematic
parameters at the joints, times the true hand-eye) looks at each target where it really lies,
the table's height field giving its centre's z and the local tilt.

How a frame is drawn (~3-5 ms at 752x480): every raw pixel's ray is known once (the
undistortion of the pixel grid); for each target an 8 px grid of rays finds the pixels it
covers, the ray -> texel homography maps those pixels into a texture whose texels are about
one image pixel (a texture per scale, cached), and cv2.remap samples it bilinearly, which makes
each edge a one-pixel ramp centred on the true edge (the area sampling of a pixel, no 0.5 px
bias). Pixel centres at integer coordinates (OpenCV's convention) in images and textures.
The image is reflectance (TABLE, PAPER, INK grey levels) times a light gain map (a linear
gradient across the image and vignetting), blurred (Gaussian, ``blur_sigma`` px), plus
Gaussian noise (``noise_sigma`` grey levels, OpenCV's RNG), truncated to 8 bits.
"""
from __future__ import annotations

from dataclasses import dataclass
import functools
import math
from typing import Iterable

import cv2
import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.targets import BoardSpec, get_dictionary
from cobot_calib_ros.core.robot_port import LandmarkImage, Sighting
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import CameraTruth, Simulation

Array = NDArray[np.float64]
TABLE, PAPER, INK = 110, 235, 22     # reflectance as grey levels under a gain of 1
GRID_PX = 8                          # spacing of the rays that find a target's pixels
MIN_DEPTH = 0.02                     # [m] a target closer to the lens is not drawn
MAX_TEXEL_PX = 64                    # largest module / square in a texture [px]
SLOPE_STEP = 1e-3                    # [m] central differences of the height field


@dataclass(frozen=True, eq=False)
class Texture:
    """A target's printed face: mono8 reflectance and texel (u, v, 1) -> plane (x, y, 1) [m]."""

    image: NDArray[np.uint8]
    plane_from_texel: Array


@functools.lru_cache(maxsize=512)
def marker_texture(dictionary: str, marker_id: int, length: float, module_px: int) -> Texture:
    """A marker of side ``length`` [m] on paper with a white margin of ceil(cells / 2) modules
    (a narrower one makes OpenCV's default minMarkerDistanceRate drop the marker),
    ``module_px`` texels a module; plane = the marker frame (centre, x right, y up)."""
    d = get_dictionary(dictionary)
    cells = d.markerSize + 2
    side = cells * module_px
    margin = (cells + 1) // 2 * module_px
    ink = cv2.aruco.generateImageMarker(d, marker_id, side, borderBits=1)
    image = cv2.copyMakeBorder(ink, margin, margin, margin, margin, cv2.BORDER_CONSTANT,
                               value=255)
    s, c = length / side, margin - 0.5 + side / 2.0    # the marker's edge is at margin - 0.5
    return Texture(_reflectance(image), np.array([[s, 0, -c * s], [0, -s, c * s], [0, 0, 1]]))


@functools.lru_cache(maxsize=128)
def board_texture(spec: BoardSpec, square_px: int) -> Texture:
    """A ChArUco board with one square of white margin, ``square_px`` texels a square; plane =
    the board frame (top-left outer grid corner, x right, y down)."""
    size = ((spec.squares_x + 2) * square_px, (spec.squares_y + 2) * square_px)
    image = spec.board().generateImage(size, marginSize=square_px, borderBits=1)
    s, o = spec.square_length / square_px, square_px - 0.5
    return Texture(_reflectance(image), np.array([[s, 0, -o * s], [0, s, -o * s], [0, 0, 1]]))


def _reflectance(printed: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Black ink and white paper as grey levels under a gain of 1."""
    return (INK + printed.astype(np.float32) * ((PAPER - INK) / 255.0) + 0.5).astype(np.uint8)


@dataclass(frozen=True)
class MarkerTarget:
    dictionary: str
    marker_id: int
    length: float                       # [m]

    def texture(self, px_per_m: float) -> Texture:
        """The texture whose module is closest to ``px_per_m`` [px/m] image pixels."""
        cells = get_dictionary(self.dictionary).markerSize + 2
        return marker_texture(self.dictionary, self.marker_id, self.length,
                              _texels(self.length / cells * px_per_m))


@dataclass(frozen=True)
class BoardTarget:
    spec: BoardSpec

    def texture(self, px_per_m: float) -> Texture:
        return board_texture(self.spec, _texels(self.spec.square_length * px_per_m))


def _texels(image_px: float) -> int:
    return int(np.clip(round(image_px), 1, MAX_TEXEL_PX))


def scaled_camera(camera: CameraModel, width: int, height: int) -> CameraModel:
    """The same lens on a sensor of another resolution: K scaled (fx, fy by the width ratio,
    the principal point by each side's ratio), D kept."""
    s, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 2] = (K[0, 2] + 0.5) * s - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return CameraModel(width, height, K, camera.D, camera.distortion_model, camera.name)


class Renderer:
    """mono8 images of targets through one camera (K, D, size) with the truth's optics."""

    def __init__(self, camera: CameraModel, truth: CameraTruth,
                 rng: np.random.Generator | None = None) -> None:
        """``rng`` draws the sensor noise (default: a fresh unseeded generator). It was
        OpenCV's global cv2.randn generator: a test's images, and with them its result, then
        depended on how many images the process had drawn before (a hand-eye test gave
        0.1232 mm alone and 0.1274 mm after other test files, out of its window)."""
        if camera.width is None or camera.height is None:
            raise ValueError('the camera model needs an image size to render')
        self.camera, self.truth = camera, truth
        h, w = camera.height, camera.width
        ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
        ideal = camera.undistort_pixels(np.stack([xs, ys], -1).reshape(-1, 2))
        K = camera.K
        rays = (ideal - K[:2, 2]) / np.diag(K)[:2]        # normalised image coordinates
        self._rays = rays.reshape(h, w, 2).astype(np.float32)
        self._grid_y = np.unique(np.r_[np.arange(0, h, GRID_PX), h - 1])
        self._grid_x = np.unique(np.r_[np.arange(0, w, GRID_PX), w - 1])
        self._grid = self._rays[np.ix_(self._grid_y, self._grid_x)].astype(np.float64)
        gx, gy = truth.light_gradient
        u, v = xs / (w - 1) - 0.5, ys / (h - 1) - 0.5
        self._gain = ((1.0 + gx * u + gy * v) * (1.0 - truth.vignetting * 2.0 * (u * u + v * v))
                      ).astype(np.float32)
        self._background = np.full((h, w), TABLE, np.uint8)
        self._noise = np.empty((h, w), np.float32)
        self._rng = rng if rng is not None else np.random.default_rng()

    def render(self, targets: Iterable[tuple[MarkerTarget | BoardTarget, Array]]
               ) -> NDArray[np.uint8]:
        """The image of ``targets``, each (target, T_optical_target), drawn in that order."""
        image = self._background.copy()
        for target, T in targets:
            self._draw(image, target, np.asarray(T, dtype=float))
        out = cv2.multiply(image, self._gain, dtype=cv2.CV_32F)
        if self.truth.blur_sigma > 0:
            out = cv2.GaussianBlur(out, (0, 0), self.truth.blur_sigma)
        if self.truth.noise_sigma > 0:
            self._rng.standard_normal(dtype=np.float32, out=self._noise)
            self._noise *= self.truth.noise_sigma
            cv2.add(out, self._noise, out)
        np.clip(out, 0.0, 255.0, out=out)
        return out.astype(np.uint8)

    def _draw(self, image: NDArray[np.uint8], target, T: Array) -> None:
        depth = T[2, 3]
        if depth < MIN_DEPTH:
            return
        texture = target.texture(self.camera.K[0, 0] / depth)
        th, tw = texture.image.shape
        # texel -> normalised ray (homogeneous), and back
        M = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ texture.plane_from_texel
        try:
            H = np.linalg.inv(M)
        except np.linalg.LinAlgError:
            return                      # seen edge-on
        uvw = self._grid @ H[:, :2].T + H[:, 2]
        ahead = uvw[..., 2] > 0
        with np.errstate(divide='ignore', invalid='ignore'):
            u, v = uvw[..., 0] / uvw[..., 2], uvw[..., 1] / uvw[..., 2]
        inside = ahead & (u >= -0.5) & (u <= tw - 0.5) & (v >= -0.5) & (v <= th - 0.5)
        if not inside.any():
            return
        rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
        gy, gx = self._grid_y, self._grid_x
        r0, r1 = max(rows[0] - 2, 0), min(rows[-1] + 2, len(gy) - 1)
        c0, c1 = max(cols[0] - 2, 0), min(cols[-1] + 2, len(gx) - 1)
        y0, y1, x0, x1 = gy[r0], gy[r1] + 1, gx[c0], gx[c1] + 1
        rays = self._rays[y0:y1, x0:x1]
        maps = cv2.perspectiveTransform(np.ascontiguousarray(rays).reshape(-1, 1, 2), H)
        maps = maps.reshape(y1 - y0, x1 - x0, 2)
        if not ahead[r0:r1 + 1, c0:c1 + 1].all():     # the plane's horizon is in view
            w = rays[..., 0] * H[2, 0] + rays[..., 1] * H[2, 1] + H[2, 2]
            maps[w <= 0] = -1e4
        roi = image[y0:y1, x0:x1].copy()
        cv2.remap(texture.image, maps, None, cv2.INTER_LINEAR, dst=roi,
                  borderMode=cv2.BORDER_TRANSPARENT)
        image[y0:y1, x0:x1] = roi


class SimCamera:
    """The simulated wrist camera: the true chain to the optical frame and the cell's
    fiducials where they really lie (cell ``landmarks:``, ``simulation: camera:``).

    ``camera`` is the nominal camera the suite is given (default the cell's; another
    resolution scales the lens); ``true_camera`` the lens that draws the images (the
    simulation's true intrinsics on the same sensor, scaled alike; the nominal without)."""

    def __init__(self, sim: Simulation, robot: SimRobot,
                 camera: CameraModel | None = None) -> None:
        cell = sim.cell
        if cell.camera is None or cell.landmarks is None or sim.camera is None:
            raise ValueError(f'cell {cell.name!r} has no camera (cell: camera:, simulation: '
                             'camera:) or no landmarks (cell: landmarks:)')
        self.sim = sim
        nominal = cell.camera.camera_model()
        self.camera = camera or nominal
        true = sim.camera.true_camera(nominal)
        if (self.camera.width, self.camera.height) != (true.width, true.height):
            true = scaled_camera(true, self.camera.width, self.camera.height)
        self.true_camera = true if sim.camera.K is not None else self.camera
        self.chain = robot.model.chain(robot.true_parameters, tool=sim.camera.T_flange_optical)
        self.targets = true_targets(sim)
        self.renderer = Renderer(self.true_camera, sim.camera, robot.image_rng)

    def T_base_optical(self, q: Array) -> Array:
        """The true optical frame in base at joints ``q`` [rad]."""
        return kinematics.fk(self.chain, q)

    def joints_looking_down(self, xy, height: float) -> Array:
        """Joints [rad] that put the TRUE camera straight above user (x, y) at ``height`` [m];
        ValueError if the true chain cannot reach it."""
        sim = self.sim
        T = sim.world.T_base_user @ frames.make_transform(frames.rot_x(np.pi), [*xy, height])
        result = kinematics.solve_ik_with_restarts(self.chain, T, sim.cell.home, sim.cell.home)
        if not result:
            raise ValueError(f'the camera cannot look down at {xy} from {height} m: '
                             f'{result.message}')
        return result.q

    def T_optical_targets(self, q: Array) -> dict[tuple[str, int], Array]:
        """(kind, id) -> true T_optical_target at joints ``q``: ('marker', id), ('board',
        first marker id)."""
        T_optical_base = frames.invert(self.T_base_optical(q))
        return {key: T_optical_base @ T_base for key, (_, T_base) in self.targets.items()}

    def render(self, q: Array) -> NDArray[np.uint8]:
        """The mono8 image the camera takes with the arm at ``q``."""
        poses = self.T_optical_targets(q)
        return self.renderer.render((self.targets[key][0], T) for key, T in poses.items())


def surface_frame(sim: Simulation, x: float, y: float) -> Array:
    """(4, 4) the true table surface at user (x, y): its height and local tilt; x axis along
    the surface's slope in user x, z up along the normal."""
    field = sim.world.height_field
    h = SLOPE_STEP
    dzdx = float(field(x + h, y) - field(x - h, y)) / (2 * h)
    dzdy = float(field(x, y + h) - field(x, y - h)) / (2 * h)
    normal = np.array([-dzdx, -dzdy, 1.0]) / math.sqrt(1.0 + dzdx ** 2 + dzdy ** 2)
    tx = np.array([1.0, 0.0, dzdx]) / math.sqrt(1.0 + dzdx ** 2)
    return frames.make_transform(np.column_stack([tx, np.cross(normal, tx), normal]),
                                 [x, y, float(field(x, y))])


def true_targets(sim: Simulation) -> dict[tuple[str, int], tuple[MarkerTarget | BoardTarget,
                                                                   Array]]:
    """(kind, id) -> (target, true T_base_target) of the cell's fiducials."""
    marks, T_base_user = sim.cell.landmarks, sim.world.T_base_user
    out = {}
    for marker_id, (x, y, _) in marks.markers.items():
        out['marker', marker_id] = (
            MarkerTarget(marks.dictionary, marker_id, marks.marker_length),
            T_base_user @ marks.T_user_marker(marker_id, surface_frame(sim, x, y)))
    if marks.board:
        spec = BoardSpec.parse(marks.board)
        x, y, _ = marks.board_pose
        out['board', spec.first_id] = (
            BoardTarget(spec), T_base_user @ marks.T_user_board(surface_frame(sim, x, y)))
    return out


class DirectCamera:
    """core.robot_port.CameraPort on a SimCamera, in-process (no ROS): for tests.

    An image is rendered at the arm's joints when asked for, and its markers (``boards``: and
    the cell's ChArUco board) detected and posed by core.landmarks, as landmark_detector does,
    with ``camera`` (default the scene's nominal camera; e.g. calibrated intrinsics).
    The clock counts: every ``now_ns`` and every image is one nanosecond later.
    """

    def __init__(self, scene: SimCamera, robot: SimRobot, boards: bool = False,
                 camera: CameraModel | None = None) -> None:
        self.scene, self.robot = scene, robot
        self.camera = camera or scene.camera     # the intrinsics detections are posed with
        marks = scene.sim.cell.landmarks
        self._board = BoardSpec.parse(marks.board) if boards and marks.board else None
        self._clock = 0
        self.images = 0          # rendered so far

    def now_ns(self) -> int:
        self._clock += 1
        return self._clock

    def landmarks_after(self, t_ns: int, wanted, max_images: int,
                        timeout: float) -> LandmarkImage:
        self._clock = max(self._clock, t_ns)
        image = self._image()
        for _ in range(1, max_images):
            if wanted(image):
                break
            image = self._image()
        return image

    def _image(self) -> LandmarkImage:
        from cobot_calib_ros.core.landmarks.detect import detect_board, detect_markers
        from cobot_calib_ros.core.landmarks.pose import estimate_board_pose, estimate_marker_pose
        gray = self.scene.render(self.robot.q)
        self.images += 1
        camera, marks = self.camera, self.scene.sim.cell.landmarks
        b = self._board        # the board's own markers are not landmarks (landmark_detector)
        board_ids = range(b.first_id, b.first_id + b.n_markers) if b is not None \
            and b.dictionary == marks.dictionary else range(0)
        seen = []
        for marker in detect_markers(gray, marks.dictionary, camera=camera):
            pose = estimate_marker_pose(marker.corners, marks.marker_length, camera)
            if pose and marker.id not in board_ids:
                seen.append(Sighting('marker', int(marker.id), pose.T_optical_target,
                                     pose.covariance))
        if self._board is not None:
            detection = detect_board(gray, self._board, camera=camera)
            pose = estimate_board_pose(detection, self._board, camera) if len(detection) \
                else None
            if pose:
                seen.append(Sighting('board', self._board.first_id, pose.T_optical_target,
                                     pose.covariance))
        return LandmarkImage(self.now_ns(), tuple(seen))


class DirectImages:
    """core.landmarks.intrinsics_capture.ImagePort on a SimCamera, in-process: the image the
    camera takes at the arm's joints, rendered when asked for (one nanosecond per call)."""

    def __init__(self, scene: SimCamera, robot: SimRobot) -> None:
        self.scene, self.robot = scene, robot
        self._clock = 0

    def now_ns(self) -> int:
        self._clock += 1
        return self._clock

    def image_after(self, t_ns: int, timeout: float) -> tuple[int, NDArray[np.uint8]]:
        self._clock = max(self._clock, t_ns) + 1
        return self._clock, self.scene.render(self.robot.q)
