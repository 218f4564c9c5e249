"""Marker and ChArUco board detection on raw images (OpenCV's aruco module).

Pixel coordinates follow OpenCV's convention: x right, y down, origin at the centre of the
top-left pixel. Marker corners are top-left, top-right, bottom-right, bottom-left of the marker
as printed. Bad input (not a mono8 / bgr8 image, empty) raises ImageError (a ValueError).

Corner refinement ``refine``:

- 'edges' (default, ours): OpenCV's SUBPIX corners, then each marker side is located to sub-pixel
  accuracy (centroid of the intensity gradient across the black border's outer edge, on 48
  profiles along the side), a straight line is fitted per side (in the undistorted image when
  a camera is given) and the corners are the lines' intersections. It removes cornerSubPix's
  inward pull on L-shaped corners: ~0.01 px on clean renderings (SUBPIX ~0.19 px), and on the
  OpenCV tutorial photos 0.39-0.43 px mean from the corners the ChArUco board pose predicts
  (SUBPIX 0.80-0.88 px). A marker it cannot fit (< 1.5 px per module, an edge missing, a corner
  moving too far, an image too large to sample) keeps its SUBPIX corners, and says so
  (MarkerDetection.refinement 'subpix').
- 'subpix': OpenCV's CORNER_REFINE_SUBPIX (cornerSubPix on each corner).
- 'apriltag': OpenCV's CORNER_REFINE_APRILTAG (AprilTag quad fitting; it replaces the candidate
  search, so it finds other/fewer markers, and is slow), shifted into OpenCV's pixel convention.
- 'none': the contour polygon's integer corners (~0.7 px).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.targets import BoardSpec, get_dictionary

# refine name -> OpenCV's cornerRefinementMethod ('edges' starts from SUBPIX)
REFINE_METHODS = {
    'edges': cv2.aruco.CORNER_REFINE_SUBPIX,
    'subpix': cv2.aruco.CORNER_REFINE_SUBPIX,
    'apriltag': cv2.aruco.CORNER_REFINE_APRILTAG,
    'none': cv2.aruco.CORNER_REFINE_NONE,
}
DEFAULT_REFINE = 'edges'
# CORNER_REFINE_APRILTAG reports corners in the AprilTag library's convention (pixel centres
# at +0.5); measured +0.46 / +0.47 px against SUBPIX on the OpenCV tutorial photos and +0.50 px
# against the apriltag reference corners. Shifted back into OpenCV's convention.
APRILTAG_OFFSET_PX = 0.5


class ImageError(ValueError):
    """The image cannot be searched (empty, not 8-bit, not mono / BGR / BGRA)."""


@dataclass(frozen=True, eq=False)
class MarkerDetection:
    """One marker: its id and (4, 2) raw-image corners [px] in OpenCV's order (TL TR BR BL);
    ``refinement`` the corner refinement its corners had ('subpix' where 'edges' was asked
    for but could not fit this marker)."""

    id: int
    corners: NDArray[np.float64]
    refinement: str

    @property
    def center(self) -> NDArray[np.float64]:
        """Intersection of the diagonals [px] (the image of the marker centre)."""
        p0, p1, p2, p3 = self.corners
        d1, d2 = p2 - p0, p3 - p1
        denom = d1[0] * d2[1] - d1[1] * d2[0]
        if abs(denom) < 1e-12:
            return self.corners.mean(axis=0)
        s = ((p1[0] - p0[0]) * d2[1] - (p1[1] - p0[1]) * d2[0]) / denom
        return p0 + s * d1


@dataclass(frozen=True, eq=False)
class BoardDetection:
    """A ChArUco board in one image: chessboard corners by ChArUco id and the markers seen.

    ``charuco_ids`` (N,) int, ``charuco_corners`` (N, 2) [px] sub-pixel chessboard corners;
    ``markers`` the board's markers found (used to interpolate the corners)."""

    charuco_ids: NDArray[np.int64]
    charuco_corners: NDArray[np.float64]
    markers: tuple[MarkerDetection, ...]

    def __len__(self) -> int:
        return len(self.charuco_ids)


def as_gray(image) -> NDArray[np.uint8]:
    """A mono8 view / copy of a mono8 (H, W) or (H, W, 1), bgr8 (H, W, 3) or bgra8 image."""
    if not isinstance(image, np.ndarray):
        raise ImageError(f'expected a numpy image array, got {type(image).__name__}')
    if image.size == 0:
        raise ImageError(f'the image is empty (shape {image.shape})')
    if image.dtype != np.uint8:
        raise ImageError(f'the image is {image.dtype}; expected uint8 (mono8 or bgr8)')
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    raise ImageError(f'the image has shape {image.shape}; expected (H, W) mono8 or '
                     f'(H, W, 3) bgr8')


def detector_parameters(refine: str = DEFAULT_REFINE, params=None) -> cv2.aruco.DetectorParameters:
    """DetectorParameters for the corner refinement ``refine`` (see REFINE_METHODS).

    ``params``: a cv2.aruco.DetectorParameters (copied) or a mapping of its attribute names
    (e.g. ``{'minMarkerDistanceRate': 0.05}``); ``refine`` overrides cornerRefinementMethod."""
    if refine not in REFINE_METHODS:
        raise ValueError(f'unknown corner refinement {refine!r}; use one of '
                         f'{", ".join(REFINE_METHODS)}')
    out = cv2.aruco.DetectorParameters()
    if isinstance(params, cv2.aruco.DetectorParameters):
        params = {name: getattr(params, name) for name in dir(params)
                  if not name.startswith('_') and not callable(getattr(params, name))}
    elif params is not None and not isinstance(params, Mapping):
        raise TypeError(f'params must be cv2.aruco.DetectorParameters or a mapping, got '
                        f'{type(params).__name__}')
    for name, value in (params or {}).items():
        if name.startswith('_') or not hasattr(out, name) or callable(getattr(out, name)):
            raise ValueError(f'unknown detector parameter {name!r}')
        setattr(out, name, value)
    out.cornerRefinementMethod = REFINE_METHODS[refine]
    return out


def search_parameters(min_marker_fraction: float) -> dict | None:
    """Detector parameters (for detector_parameters' ``params``) that search only markers whose
    side is at least ``min_marker_fraction`` of the image's larger side, with OpenCV's ArUco 3
    method: candidates are searched on the image scaled down accordingly, corners on the full
    image. None (the full search) for 0."""
    if min_marker_fraction <= 0.0:
        return None
    return {'useAruco3Detection': True,
            'minMarkerLengthRatioOriginalImg': float(min_marker_fraction)}


def _dictionary(dictionary) -> cv2.aruco.Dictionary:
    if isinstance(dictionary, cv2.aruco.Dictionary):
        return dictionary
    return get_dictionary(dictionary)


# 'edges' refinement: per side EDGE_PROFILES gradient profiles across the black border's outer
# edge, each EDGE_SAMPLES samples over +-EDGE_HALF_WIDTH_MODULES of a module (1 to 6 px; the
# border is one module wide, so the window must not reach its inner edge).
EDGE_PROFILES = 48
EDGE_SAMPLES = 33
EDGE_HALF_WIDTH_MODULES = 0.75
EDGE_ITERATIONS = 4
# [px] a pass that moved no corner more than this ends the refinement: the passes converge by
# ~20x each (bench_detector's 1280x800 markers: 0.0075 px, then 0.0004), so the corners are then
# within ~0.001 px of the fixed point. 0.01 saved a third pass (1.5 ms of 6 an image) but moved
# the sample bags' replayed landmark frames off their live ones (the checks' tolerance 1e-6 m)
EDGE_CONVERGED_PX = 0.005
EDGE_MIN_MODULE_PX = 1.5      # smaller markers keep their SUBPIX corners
# cv2.remap asserts that its source and destination are below SHRT_MAX in both sides
REMAP_MAX_SIDE = 32767 - 1


def _fit_lines(points: NDArray[np.float64], weights: NDArray[np.float64]):
    """Weighted total-least-squares lines n . p = c (|n| = 1) through (..., M, 2) points."""
    wsum = np.maximum(weights.sum(-1), 1e-12)
    mu = (points * weights[..., None]).sum(-2) / wsum[..., None]
    q = points - mu[..., None, :]
    sxx = (weights * q[..., 0] ** 2).sum(-1)
    syy = (weights * q[..., 1] ** 2).sum(-1)
    sxy = (weights * q[..., 0] * q[..., 1]).sum(-1)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)          # direction of the line
    n = np.stack([-np.sin(theta), np.cos(theta)], axis=-1)
    return n, (n * mu).sum(-1)


def _sample_profiles(image: NDArray[np.float32], map_x: NDArray[np.float32],
                     map_y: NDArray[np.float32]) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Bilinear reads (BORDER_REPLICATE) of ``image`` at (Q, ...) maps: (values (Q, ...),
    sampled (Q,) bool).

    cv2.remap takes at most REMAP_MAX_SIDE rows and columns in its source and destination, so
    the markers go in batches under that many rows, and an image larger than that is read
    through the crop around each marker (the same pixels: the crop holds every pixel a read
    touches). A marker whose crop is still too large is not sampled (zeros)."""
    q = len(map_x)
    out = np.zeros(map_x.shape, dtype=np.float32)
    sampled = np.zeros(q, dtype=bool)
    h, w = image.shape[:2]
    rows_per_marker = max(1, map_x[0].size // EDGE_SAMPLES) if q else 1
    small = h <= REMAP_MAX_SIDE and w <= REMAP_MAX_SIDE
    batch = max(1, REMAP_MAX_SIDE // rows_per_marker) if small else 1
    for a in range(0, q, batch):
        mx, my = map_x[a:a + batch], map_y[a:a + batch]
        source, x0, y0 = image, 0, 0
        if not small:
            x0 = int(np.clip(np.floor(np.nanmin(mx)) - 1, 0, w - 1))
            y0 = int(np.clip(np.floor(np.nanmin(my)) - 1, 0, h - 1))
            x1 = int(np.clip(np.ceil(np.nanmax(mx)) + 2, x0 + 1, w))
            y1 = int(np.clip(np.ceil(np.nanmax(my)) + 2, y0 + 1, h))
            if x1 - x0 > REMAP_MAX_SIDE or y1 - y0 > REMAP_MAX_SIDE:
                continue
            source = image[y0:y1, x0:x1]
        values = cv2.remap(source, (mx - x0).reshape(-1, EDGE_SAMPLES),
                           (my - y0).reshape(-1, EDGE_SAMPLES), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        out[a:a + batch] = values.reshape(mx.shape)
        sampled[a:a + batch] = True
    return out, sampled


def refine_corners_edges(gray: NDArray, corners: NDArray[np.float64], cells: int, *,
                         camera: CameraModel | None = None,
                         iterations: int = EDGE_ITERATIONS):
    """Marker corners from straight lines fitted to the markers' four outer edges.

    ``corners`` (Q, 4, 2) (TL TR BR BL each); ``cells``: a marker's side in modules
    (markerSize + 2 border bits). Each side's edge is located to sub-pixel accuracy along
    EDGE_PROFILES profiles (centroid of the intensity gradient), a line is fitted (weighted
    total least squares, one outlier pass; in the undistorted image when ``camera`` is given,
    where the sides are straight) and the corners are the intersections of adjacent lines.
    Returns (corners (Q, 4, 2), fitted (Q,) bool); a marker is left as it was when it is too
    small, an edge is missing (occlusion, low contrast), a corner would move by more than
    max(2 px, a module) or it cannot be sampled (_sample_profiles)."""
    image = gray if gray.dtype == np.float32 else gray.astype(np.float32)
    h, w_img = image.shape[:2]
    start = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
    c = start.copy()
    q = len(c)
    fitted = np.ones(q, dtype=bool)
    if q == 0:
        return c, fitted
    sign = None
    u = np.linspace(0.0, 1.0, EDGE_PROFILES)
    v = np.linspace(-1.0, 1.0, EDGE_SAMPLES)
    for _ in range(iterations):
        sides = np.roll(c, -1, axis=1) - c                              # (Q, 4, 2)
        lengths = np.linalg.norm(sides, axis=-1)
        module = lengths.mean(axis=1) / cells
        # a module across each side (foreshortened views: from the neighbouring sides)
        across = np.minimum(np.roll(lengths, 1, axis=1), np.roll(lengths, -1, axis=1)) / cells
        fitted &= (across.min(axis=1) >= EDGE_MIN_MODULE_PX) & (lengths.min(axis=1) >= 4.0)
        d = sides / np.maximum(lengths, 1e-9)[..., None]
        n = np.stack([d[..., 1], -d[..., 0]], axis=-1)
        mid = c + 0.5 * sides - c.mean(axis=1, keepdims=True)
        n *= np.where((n * mid).sum(-1) < 0, -1.0, 1.0)[..., None]    # outward
        half = np.clip(EDGE_HALF_WIDTH_MODULES * across, 1.0, 6.0)      # (Q, 4)
        margin = np.minimum(lengths / 4.0, np.maximum(2.0, 0.75 * module)[:, None])
        t = margin[..., None] + (lengths - 2.0 * margin)[..., None] * u  # (Q, 4, P)
        s = half[..., None] * v                                          # (Q, 4, S)
        base = c[:, :, None, :] + t[..., None] * d[:, :, None, :]        # (Q, 4, P, 2)
        s32 = s.astype(np.float32)[:, :, None, :]
        maps = [(base[..., i].astype(np.float32)[..., None] +
                 s32 * n[..., i].astype(np.float32)[:, :, None, None])
                for i in (0, 1)]
        prof, sampled = _sample_profiles(image, maps[0], maps[1])
        fitted &= sampled
        if sign is None:    # dark border inside, light outside; inverted markers the other way
            k = EDGE_SAMPLES // 2
            sign = np.where(prof[..., k + 1:].mean(axis=(1, 2, 3)) >=
                            prof[..., :k].mean(axis=(1, 2, 3)), 1.0, -1.0)
        grad = np.clip(sign[:, None, None, None] * np.diff(prof, axis=-1), 0.0, None)
        s_mid = 0.5 * (s[..., 1:] + s[..., :-1])                         # (Q, 4, S-1)
        strength = grad.sum(-1)                                          # (Q, 4, P)
        offset = (grad * s_mid[:, :, None, :]).sum(-1) / np.maximum(strength, 1e-12)
        inside = (base[..., 0] >= 0) & (base[..., 0] <= w_img - 1) & \
            (base[..., 1] >= 0) & (base[..., 1] <= h - 1)
        valid = inside & (strength > 0.2 * np.maximum(
            np.median(strength, axis=-1, keepdims=True), 1e-6))
        edge = base + offset[..., None] * n[:, :, None, :]
        if camera is not None:
            edge = camera.undistort_pixels(edge.reshape(-1, 2)).reshape(edge.shape)
        weight = strength * valid
        normal, offs = _fit_lines(edge, weight)
        residual = np.abs((edge * normal[..., None, :]).sum(-1) - offs[..., None])
        ranked = np.sort(np.where(valid, residual, np.inf), axis=-1)
        count = valid.sum(-1)
        mad = 1.4826 * np.take_along_axis(ranked, np.maximum(count - 1, 0)[..., None] // 2,
                                          axis=-1)[..., 0]
        keep = valid & (residual <= np.maximum(3.0 * mad, 0.1)[..., None])
        normal, offs = _fit_lines(edge, strength * keep)
        fitted &= (keep.sum(-1) >= 3).all(axis=1)
        n1, c1 = np.roll(normal, 1, axis=1), np.roll(offs, 1, axis=1)    # the previous side
        det = n1[..., 0] * normal[..., 1] - n1[..., 1] * normal[..., 0]
        fitted &= (np.abs(det) > 1e-6).all(axis=1)
        det = np.where(np.abs(det) > 1e-6, det, 1.0)
        new = np.stack([(c1 * normal[..., 1] - offs * n1[..., 1]) / det,
                        (n1[..., 0] * offs - normal[..., 0] * c1) / det], axis=-1)
        if camera is not None:
            new = camera.distort_pixels(new.reshape(-1, 2)).reshape(new.shape)
        fitted &= np.isfinite(new).all(axis=(1, 2))
        fitted &= np.linalg.norm(np.nan_to_num(new - start, nan=1e9), axis=-1).max(axis=1) \
            <= np.maximum(2.0, module)
        moved = np.abs(np.where(fitted[:, None, None], new - c, 0.0)).max()
        c = np.where(fitted[:, None, None], new, start)
        if moved < EDGE_CONVERGED_PX:
            break
    return c, fitted


def _markers(gray, corners, ids, refine: str, cells: int,
             camera: CameraModel | None) -> list[MarkerDetection]:
    if ids is None or len(ids) == 0:
        return []
    shift = APRILTAG_OFFSET_PX if refine == 'apriltag' else 0.0
    quads = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2) - shift
    applied = np.full(len(quads), refine, dtype=object)
    if refine == 'edges':
        quads, fitted = refine_corners_edges(gray, quads, cells, camera=camera)
        applied[~fitted] = 'subpix'
    found = [MarkerDetection(int(i), c, str(r))
             for i, c, r in zip(np.asarray(ids).ravel(), quads, applied)]
    return sorted(found, key=lambda m: m.id)


class MarkerFinder:
    """detect_markers in two halves, for a live camera: ``find`` (OpenCV's search, which releases
    the GIL) and ``finish`` (the corner refinement, in numpy), so that a pipeline can search one
    image while it refines the previous one; the OpenCV detector is built once.

    ``find`` and ``finish`` may run on different threads; one ``find`` at a time."""

    def __init__(self, dictionary, *, refine: str = DEFAULT_REFINE, params=None) -> None:
        self.refine = refine
        self.params = detector_parameters(refine, params)
        self.dictionary = _dictionary(dictionary)
        self.cells = self.dictionary.markerSize + 2 * self.params.markerBorderBits
        self._detector = cv2.aruco.ArucoDetector(self.dictionary, self.params)

    def find(self, image) -> tuple:
        """The markers OpenCV finds (its corners, unrefined by ``finish``) in a mono8 / bgr8
        image: an opaque value for ``finish``."""
        gray = as_gray(image)
        corners, ids, _rejected = self._detector.detectMarkers(gray)
        return gray, corners, ids

    def finish(self, found: tuple, camera: CameraModel | None = None) -> list[MarkerDetection]:
        """The markers of ``find``'s result, refined, sorted by id (as detect_markers)."""
        gray, corners, ids = found
        return _markers(gray, corners, ids, self.refine, self.cells, camera)


def detect_markers(image, dictionary, *, refine: str = DEFAULT_REFINE, params=None,
                   camera: CameraModel | None = None) -> list[MarkerDetection]:
    """The markers of ``dictionary`` (a name such as 'DICT_6X6_250' or a cv2.aruco.Dictionary)
    in a mono8 / bgr8 image, sorted by id (a marker seen twice is listed twice).

    ``refine``: 'edges', 'subpix', 'apriltag' or 'none' (module docstring); ``params``: detector
    parameters (see detector_parameters); ``camera``: lets 'edges' fit straight sides in the
    undistorted image (worth it on wide-angle lenses). For many images, MarkerFinder."""
    finder = MarkerFinder(dictionary, refine=refine, params=params)
    return finder.finish(finder.find(image), camera)


def _smoothed_windows(gray: NDArray, pts: NDArray[np.float64], reach: int,
                      sigma: float) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """The image smoothed with a Gaussian of ``sigma`` where it is read within ``reach`` [px]
    of the points: (image, origin (N, 2)); point i's pixel (x, y) is image[y - origin_y,
    x - origin_x] (bilinear reads, BORDER_REPLICATE outside the image).

    Instead of smoothing the whole image (7 ms of a 15 ms board detection at 1280x800), each
    point gets a tile of the image around it, smoothed alone and padded by replication where it
    leaves the image; the tiles are stacked. A tile reaches the Gaussian's support beyond the
    window, so the pixels read are those of the whole image smoothed (cv2.GaussianBlur's own
    border at the image's edges)."""
    image = np.asarray(gray)
    h, w = image.shape[:2]
    centre = np.rint(pts).astype(np.int64)
    # cv2.GaussianBlur's kernel for float images: ksize = round(8 sigma + 1) | 1
    half = reach + 1 + int(np.ceil(4.0 * sigma)) + 1
    size = 2 * half + 1
    if not (len(pts) * size * size < h * w and (centre >= 0).all() and
            (centre[:, 0] < w).all() and (centre[:, 1] < h).all()):
        whole = cv2.GaussianBlur(np.asarray(gray, dtype=np.float32), (0, 0), sigma)
        return whole, np.zeros((len(pts), 2))
    tiles = np.empty((len(pts) * size, size), dtype=np.float32)
    for i, (cx, cy) in enumerate(centre):
        x0, y0 = cx - half, cy - half
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + size, w), min(y0 + size, h)
        tile = cv2.GaussianBlur(image[ya:yb, xa:xb].astype(np.float32), (0, 0), sigma)
        tiles[i * size:(i + 1) * size] = cv2.copyMakeBorder(
            tile, ya - y0, y0 + size - yb, xa - x0, x0 + size - xb, cv2.BORDER_REPLICATE)
    origin = centre - half
    origin[:, 1] -= np.arange(len(pts)) * size
    return tiles, origin.astype(np.float64)


def refine_saddle_points(gray: NDArray, points: NDArray[np.float64], radius: int, *,
                         iterations: int = 4) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Chessboard (X-) corners to sub-pixel accuracy as saddle points of the smoothed image.

    A quadratic surface is fitted (Gaussian-weighted least squares) to the image smoothed with
    sigma = radius / 3 over a (2 radius + 1)^2 window around each point, and the point moves to
    the surface's saddle point, window recentred ``iterations`` times. ``radius`` [px] must
    keep the window off other features (the ChArUco markers' corners). Returns (points (N, 2),
    refined (N,) bool); a point without a saddle there, or moving more than ``radius``, is
    kept as it was. ~0.005 px on clean renderings where cornerSubPix in OpenCV's ChArUco
    detector leaves ~0.04 px."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = int(radius)
    if len(pts) == 0 or r < 1:
        return pts.copy(), np.zeros(len(pts), dtype=bool)
    sigma = max(0.7, r / 3.0)
    image, origin = _smoothed_windows(gray, pts, 2 * r + 2, sigma)
    ys, xs = np.mgrid[-r:r + 1, -r:r + 1].astype(np.float64)
    x, y = xs.ravel(), ys.ravel()
    weight = np.exp(-(x ** 2 + y ** 2) / (2.0 * (r / 1.5) ** 2))
    design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)]) * weight[:, None]
    solve = np.linalg.pinv(design)                                    # (6, window)
    out = pts.copy()
    ok = np.ones(len(pts), dtype=bool)
    for _ in range(iterations):
        mx = (out[:, 0, None] - origin[:, 0, None] + x[None, :]).astype(np.float32)
        my = (out[:, 1, None] - origin[:, 1, None] + y[None, :]).astype(np.float32)
        patch = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        a, b, c, d, e, _ = solve @ (patch.astype(np.float64) * weight[None, :]).T
        det = 4.0 * a * c - b * b                      # < 0: a saddle
        safe = np.where(det < 0, det, -1.0)
        step = np.stack([(b * e - 2.0 * c * d) / safe, (b * d - 2.0 * a * e) / safe], axis=1)
        ok &= (det < 0) & (np.abs(step).max(axis=1) <= r)
        out = np.where(ok[:, None], out + step, pts)
        ok &= np.linalg.norm(out - pts, axis=1) <= r
        out = np.where(ok[:, None], out, pts)
        if np.abs(step[ok]).max(initial=0.0) < 1e-3:
            break
    return out, ok


def _saddle_radius(board: cv2.aruco.CharucoBoard, corners: NDArray[np.float64],
                   markers: tuple[MarkerDetection, ...]) -> int:
    """Window radius [px] that keeps a chessboard corner's window off the marker corners
    (which sit (square - marker) / sqrt(2) from it), from the near-side scale seen."""
    square, marker = board.getSquareLength(), board.getMarkerLength()
    if markers:
        sides = np.concatenate([np.linalg.norm(np.roll(m.corners, -1, 0) - m.corners, axis=1)
                                for m in markers])
        square_px = float(np.percentile(sides, 10)) * square / marker
    elif len(corners) >= 2:
        dist = np.linalg.norm(corners[:, None] - corners[None], axis=-1)
        np.fill_diagonal(dist, np.inf)
        square_px = float(np.percentile(dist.min(axis=1), 10))
    else:
        return 0
    gap_px = square_px * (square - marker) / (np.sqrt(2.0) * square)
    return int(np.clip(np.floor(0.7 * gap_px), 2, 6))


class BoardFinder:
    """detect_board in two halves, as MarkerFinder: ``find`` (OpenCV's ChArUco search, GIL
    released) and ``finish`` (the markers' refinement and the saddle points, in numpy); the
    OpenCV detector is built once."""

    def __init__(self, board: BoardSpec | cv2.aruco.CharucoBoard, *,
                 refine: str = DEFAULT_REFINE, params=None, refine_markers: bool = True,
                 saddle: bool = True) -> None:
        self.board = board.board() if isinstance(board, BoardSpec) else board
        self.refine = refine
        self.saddle = saddle
        charuco_params = cv2.aruco.CharucoParameters()
        charuco_params.tryRefineMarkers = bool(refine_markers)
        self.params = detector_parameters(refine, params)
        self.cells = self.board.getDictionary().markerSize + 2 * self.params.markerBorderBits
        self._detector = cv2.aruco.CharucoDetector(self.board, charuco_params, self.params)

    def find(self, image) -> tuple:
        """The board as OpenCV finds it in a mono8 / bgr8 image: an opaque value for
        ``finish``."""
        gray = as_gray(image)
        return (gray, *self._detector.detectBoard(gray))

    def finish(self, found: tuple, camera: CameraModel | None = None) -> BoardDetection:
        """``find``'s result as a BoardDetection (as detect_board)."""
        gray, corners, ids, marker_corners, marker_ids = found
        markers = tuple(_markers(gray, marker_corners, marker_ids, self.refine, self.cells,
                                 camera))
        if ids is None or len(ids) == 0:
            return BoardDetection(np.zeros(0, dtype=np.int64), np.zeros((0, 2)), markers)
        ids = np.asarray(ids, dtype=np.int64).ravel()
        corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        if self.saddle:
            corners, _ = refine_saddle_points(gray, corners, _saddle_radius(self.board, corners,
                                                                             markers))
        order = np.argsort(ids, kind='stable')
        return BoardDetection(ids[order], corners[order], markers)


def detect_board(image, board: BoardSpec | cv2.aruco.CharucoBoard, *,
                 refine: str = DEFAULT_REFINE, params=None, refine_markers: bool = True,
                 saddle: bool = True, camera: CameraModel | None = None) -> BoardDetection:
    """A ChArUco board's chessboard corners and markers in a mono8 / bgr8 image; none found
    gives an empty detection.

    The corners are OpenCV's (interpolated from the markers seen, cornerSubPix'ed), then with
    ``saddle`` located again as saddle points (refine_saddle_points; ~8x closer to the truth on
    renderings, lower reprojection error on the tutorial photos). ``refine``/``params``/
    ``camera`` as for detect_markers (they apply to the board's markers); ``refine_markers``
    lets OpenCV look again for missed markers where the board says they are. For many images,
    BoardFinder."""
    finder = BoardFinder(board, refine=refine, params=params, refine_markers=refine_markers,
                         saddle=saddle)
    return finder.finish(finder.find(image), camera)
