"""Camera intrinsics from views of a calibration board: K and D of the raw image.

A view is the board's corners seen in one image: object points (board frame [m]) and their
raw-image pixels. ``calibrate_intrinsics`` fits one of the sensor_msgs/CameraInfo models:

- 'plumb_bob': cv2.calibrateCamera, k1 k2 p1 p2 k3 (OpenCV's default flags);
- 'rational_polynomial': cv2.calibrateCamera with CALIB_RATIONAL_MODEL, k1 k2 p1 p2 k3 k4 k5 k6;
- 'equidistant': cv2.fisheye.calibrate (CALIB_RECOMPUTE_EXTRINSIC | CALIB_FIX_SKEW), k1..k4.

Then: the RMS reprojection error of each view; views above OUTLIER_FACTOR x the median (and
OUTLIER_MIN_PX) are named outliers, dropped, and the model fitted once more without them; the
held-out error (k-fold over views: each fold is fitted without its views, whose poses are then
solved with those intrinsics alone); the coverage of the image (grid cells holding corners)
and of board tilts, with what is missing; and the gate (nothing becomes active whose held-out
error its fit does not explain). Reprojection errors are RMS over points of the pixel distance.

Refused (core.errors.Refusal, its failure's code an ErrorCode): fewer than MIN_VIEWS views
(TOO_FEW_POINTS), a view with fewer than MIN_POINTS corners or non-finite values
(INVALID_INPUT), views all nearly fronto-parallel (the focal length is then not observable) or
that OpenCV cannot calibrate (DEGENERATE_POINTS).
"""
from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode as E, Failure, Refusal
from cobot_calib_ros.core.landmarks.camera import CameraModel

Array = NDArray[np.float64]

MODELS = ('plumb_bob', 'rational_polynomial', 'equidistant')
MIN_VIEWS = 4
MIN_POINTS = 6
OUTLIER_FACTOR = 3.0
OUTLIER_MIN_PX = 0.3          # a view this close to its fit is never an outlier
FOLDS = 5
DEGENERATE_TILT_DEG = 5.0     # every view tilted less: refused (focal length unobservable)
GOOD_TILT_DEG = 15.0          # a tilt direction counts as covered from this tilt on
COVERAGE_GRID = (4, 4)        # (rows, cols) cells of the image for the coverage fraction
# gate: the held-out error may exceed the fit's by this factor (fewer residual degrees of
# freedom, and the held-out poses are solved alone) before the model is said to overfit
HELDOUT_RATIO_MAX = 1.5
MAX_RMS_PX = 1.0
MIN_COVERAGE = 0.5
GOOD_START_PX = 2.0            # a fisheye start converging below this is taken
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
_REGIONS = (('top-left', 'top', 'top-right'), ('left', 'centre', 'right'),
            ('bottom-left', 'bottom', 'bottom-right'))
_TILTS = ('left', 'right', 'up', 'down')


def _refusal(code: E, message: str) -> Refusal:
    """Views that cannot be calibrated, and why."""
    return Refusal(Failure(code, message))


@dataclass(frozen=True, eq=False)
class BoardView:
    """One image's board corners: ``object_points`` (N, 3) in the board frame [m] and
    ``image_points`` (N, 2) raw-image pixels; ``name`` names it in messages (a file, a stamp)."""

    name: str
    object_points: Array
    image_points: Array

    def __post_init__(self):
        obj = np.asarray(self.object_points, dtype=np.float64).reshape(-1, 3)
        img = np.asarray(self.image_points, dtype=np.float64).reshape(-1, 2)
        if len(obj) != len(img):
            raise _refusal(E.INVALID_INPUT, f'view {self.name}: {len(obj)} object points '
                           f'but {len(img)} image points')
        if not (np.isfinite(obj).all() and np.isfinite(img).all()):
            raise _refusal(E.INVALID_INPUT, f'view {self.name}: points are not finite '
                           '(NaN or inf); drop the view or fix the detection')
        if len(obj) < MIN_POINTS:
            raise _refusal(E.INVALID_INPUT, f'view {self.name}: {len(obj)} corners, at '
                           f'least {MIN_POINTS} needed; drop the view')
        object.__setattr__(self, 'object_points', obj)
        object.__setattr__(self, 'image_points', img)


@dataclass(frozen=True)
class Coverage:
    """Where the corners were in the image and how the board was tilted.

    ``cells``: (rows, cols) bool, a COVERAGE_GRID cell holding a corner of some view;
    ``fraction`` of the cells; ``regions`` and ``tilts`` missing: the 3 x 3 regions of the
    image with no corner, the tilt directions (board turned left / right / up / down by at
    least GOOD_TILT_DEG) no view has; ``max_tilt_deg`` of the views."""

    cells: NDArray[np.bool_]
    fraction: float
    missing_regions: tuple[str, ...]
    missing_tilts: tuple[str, ...]
    max_tilt_deg: float

    @property
    def complete(self) -> bool:
        return not self.missing_regions and not self.missing_tilts

    @property
    def message(self) -> str:
        """What views are still missing ('' when none)."""
        parts = []
        if self.missing_regions:
            parts.append(f'corners in the image {", ".join(self.missing_regions)}')
        if self.missing_tilts:
            parts.append(f'the board tilted {", ".join(self.missing_tilts)} by '
                         f'{GOOD_TILT_DEG:.0f} deg or more')
        return ('missing: ' + '; '.join(parts)) if parts else ''


@dataclass(frozen=True, eq=False)
class IntrinsicsFit:
    """A calibrated camera and how well it holds: RMS errors [px] of the fit (views used),
    per view (every view, outliers included, against the final intrinsics), held out."""

    camera: CameraModel
    rms_px: float
    view_rms_px: dict[str, float]
    outlier_views: tuple[str, ...]
    heldout_rms_px: float
    coverage: Coverage
    views_used: int
    poses: dict[str, tuple[Array, Array]] = field(repr=False)   # name -> (rvec, tvec)
    gate_problem: str = ''

    @property
    def model(self) -> str:
        return self.camera.distortion_model


def calibrate_intrinsics(views: Sequence[BoardView], image_size: tuple[int, int],
                         model: str = 'plumb_bob', *, name: str = '',
                         outlier_factor: float = OUTLIER_FACTOR, folds: int = FOLDS,
                         max_rms_px: float = MAX_RMS_PX) -> IntrinsicsFit:
    """Intrinsics of ``model`` from ``views`` of an image of ``image_size`` (width, height)
    [px]; ``name`` the camera_name. Refusal when the views cannot determine them."""
    width, height = (int(v) for v in image_size)
    if width <= 0 or height <= 0:
        raise _refusal(E.INVALID_INPUT, f'image size must be positive, got {image_size}')
    if model not in MODELS:
        raise _refusal(E.INVALID_INPUT, f'unknown model {model!r}; use one of '
                       f'{", ".join(MODELS)}')
    views = list(views)
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise _refusal(E.INVALID_INPUT, 'view names must be unique')
    _check_count(views, model)
    size = (width, height)
    camera, poses = _fit(views, size, model, name)
    _check_tilts(views, poses)
    view_rms = _view_rms(camera, views, poses)
    limit = max(outlier_factor * float(np.median(list(view_rms.values()))), OUTLIER_MIN_PX)
    outliers = tuple(n for n, r in view_rms.items() if r > limit)
    used = [v for v in views if v.name not in outliers]
    if not outliers or len(used) < MIN_VIEWS:      # nothing to drop, or too few would be left
        outliers, used = (), views
    else:
        camera, poses = _fit(used, size, model, name, guess=camera)
        poses.update({v.name: solve_view_pose(camera, v) for v in views if v.name in outliers})
        view_rms = _view_rms(camera, views, poses)
    fit = IntrinsicsFit(camera, _rms(camera, used, poses), view_rms, outliers,
                        _heldout_rms(used, size, model, name, camera, folds),
                        image_coverage(views, poses, size), len(used), poses)
    gate = gate_problem(fit, max_rms_px)
    return dataclasses.replace(fit, gate_problem='' if gate is None else gate.message)


def gate_problem(fit: IntrinsicsFit, max_rms_px: float = MAX_RMS_PX) -> Failure | None:
    """None if ``fit`` may become a camera's active intrinsics, else an IMPLAUSIBLE_FIT
    Failure saying why not: the held-out
    error its fit does not explain (overfitting: too few or too alike views), a fit error above
    ``max_rms_px`` (bad detections, wrong model), or corners on too little of the image."""
    problems = []
    if fit.rms_px > max_rms_px:
        problems.append(f'reprojection RMS {fit.rms_px:.3f} px > {max_rms_px:g} px (bad '
                        'detections or the wrong distortion model)')
    if not np.isfinite(fit.heldout_rms_px):
        problems.append(f'{fit.views_used} views leave none to hold out with {MIN_VIEWS} to '
                        'fit: the fit cannot be checked; add views')
    elif fit.heldout_rms_px > HELDOUT_RATIO_MAX * fit.rms_px:
        problems.append(f'held-out RMS {fit.heldout_rms_px:.3f} px > {HELDOUT_RATIO_MAX:g} x '
                        f'the fit\'s {fit.rms_px:.3f} px: the model overfits these views; add '
                        'views')
    if fit.coverage.fraction < MIN_COVERAGE:
        problems.append(f'corners cover {100 * fit.coverage.fraction:.0f} % of the image '
                        f'(< {100 * MIN_COVERAGE:.0f} %)')
    if problems and not fit.coverage.complete:
        problems.append(fit.coverage.message)
    return Failure(E.IMPLAUSIBLE_FIT, '; '.join(problems)) if problems else None


def image_coverage(views: Sequence[BoardView], poses: dict[str, tuple[Array, Array]],
                   image_size: tuple[int, int]) -> Coverage:
    """Coverage of the image by the views' corners and of tilts by their poses (rvec, tvec
    of the board in the camera; views without a pose count for the image only)."""
    width, height = image_size
    pts = np.concatenate([v.image_points for v in views]) if views else np.zeros((0, 2))
    inside = (pts[:, 0] >= -0.5) & (pts[:, 0] < width - 0.5) & \
        (pts[:, 1] >= -0.5) & (pts[:, 1] < height - 0.5)
    pts = pts[inside]

    def occupied(rows: int, cols: int) -> NDArray[np.bool_]:
        grid = np.zeros((rows, cols), dtype=bool)
        r = np.clip(((pts[:, 1] + 0.5) * rows / height).astype(int), 0, rows - 1)
        c = np.clip(((pts[:, 0] + 0.5) * cols / width).astype(int), 0, cols - 1)
        grid[r, c] = True
        return grid

    cells = occupied(*COVERAGE_GRID)
    regions = occupied(3, 3)
    missing_regions = tuple(_REGIONS[r][c] for r in range(3) for c in range(3)
                            if not regions[r, c])
    seen, max_tilt = set(), 0.0
    for v in views:
        if v.name not in poses:
            continue
        tilt, direction = _tilt(poses[v.name][0])
        max_tilt = max(max_tilt, tilt)
        if tilt >= GOOD_TILT_DEG:
            seen.update(direction)
    return Coverage(cells, float(cells.mean()), missing_regions,
                    tuple(t for t in _TILTS if t not in seen), max_tilt)


def _tilt(rvec: ArrayLike) -> tuple[float, set[str]]:
    """(angle [deg] between the board's normal and the optical axis, the directions it is
    turned: 'left' / 'right' (about the image's vertical), 'up' / 'down' (its horizontal))."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    n = R[:, 2] * (1.0 if R[2, 2] >= 0 else -1.0)         # normal pointing away from the lens
    angle = float(np.degrees(np.arccos(np.clip(n[2], -1.0, 1.0))))
    ax, ay = np.degrees(np.arctan2(n[0], n[2])), np.degrees(np.arctan2(n[1], n[2]))
    out = set()
    if abs(ax) >= GOOD_TILT_DEG:
        out.add('right' if ax > 0 else 'left')
    if abs(ay) >= GOOD_TILT_DEG:
        out.add('down' if ay > 0 else 'up')
    return angle, out


def _check_count(views: Sequence[BoardView], model: str) -> None:
    if len(views) < MIN_VIEWS:
        raise _refusal(E.TOO_FEW_POINTS, f'{len(views)} views of the board; at least '
                       f'{MIN_VIEWS} are needed ({model}), 15-30 over the whole image '
                       'and tilted both ways are recommended')
    for v in views:
        if np.ptp(v.object_points[:, 2]) > 1e-9 or abs(v.object_points[0, 2]) > 1e-9:
            raise _refusal(E.INVALID_INPUT, f'view {v.name}: object points must lie on the '
                           'board plane z = 0')


def _check_tilts(views: Sequence[BoardView], poses) -> None:
    tilts = [_tilt(poses[v.name][0])[0] for v in views]
    if max(tilts) < DEGENERATE_TILT_DEG:
        raise _refusal(E.DEGENERATE_POINTS, f'every view is nearly fronto-parallel (the '
                       f'largest tilt is {max(tilts):.1f} deg < {DEGENERATE_TILT_DEG:g} '
                       'deg): the focal length cannot be told from the distance; tilt '
                       'the board 20-40 deg left, right, up and down')


def _fit(views: Sequence[BoardView], size: tuple[int, int], model: str, name: str,
         guess: CameraModel | None = None) -> tuple[CameraModel, dict[str, tuple[Array, Array]]]:
    """(camera, {view name: (rvec, tvec)}) of one OpenCV calibration of ``views``."""
    obj = [v.object_points.astype(np.float32).reshape(-1, 1, 3) for v in views]
    img = [v.image_points.astype(np.float32).reshape(-1, 1, 2) for v in views]
    try:
        if model == 'equidistant':
            K, D, rvecs, tvecs = _fit_fisheye(views, size, guess)
        else:
            flags = cv2.CALIB_RATIONAL_MODEL if model == 'rational_polynomial' else 0
            K0, D0 = None, None
            if guess is not None:
                flags |= cv2.CALIB_USE_INTRINSIC_GUESS
                K0, D0 = guess.K.copy(), np.zeros(14)
                D0[:len(guess.D)] = guess.D
            _, K, D, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, K0, D0, flags=flags,
                                                        criteria=_CRITERIA)
            D = np.asarray(D, dtype=np.float64).ravel()[:8 if flags & cv2.CALIB_RATIONAL_MODEL
                                                        else 5]
    except cv2.error as e:
        raise _refusal(E.DEGENERATE_POINTS, f'OpenCV could not calibrate these views: '
                       f'{(e.err or str(e)).strip()}') from None
    try:
        camera = CameraModel(size[0], size[1], K, D, model, name)
    except ValueError as e:
        raise _refusal(E.DEGENERATE_POINTS, f'the calibration diverged ({e}); add '
                       'views tilted both ways over the whole image') from None
    poses = {v.name: (np.asarray(r, dtype=np.float64).ravel(),
                      np.asarray(t, dtype=np.float64).ravel())
             for v, r, t in zip(views, rvecs, tvecs)}
    return camera, poses


def _fit_fisheye(views, size, guess: CameraModel | None):
    """cv2.fisheye.calibrate from ``guess`` or, without one, from f = max(w, h) / pi (OpenCV's
    own start) and focal lengths around it, the first whose fit is below GOOD_START_PX (else
    the best): the fisheye solver has no closed-form start and diverges from a poor one (its
    own initialisation did on OpenCV's 3cams-hetero fisheye views: RMS 548 px)."""
    obj = [v.object_points.reshape(1, -1, 3) for v in views]
    img = [v.image_points.reshape(1, -1, 2) for v in views]
    flags = cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
    w, h = size
    if guess is not None:
        starts = [(guess.K, guess.D)]
    else:
        f0 = max(w, h) / np.pi
        starts = [(np.array([[f * f0, 0, (w - 1) / 2], [0, f * f0, (h - 1) / 2], [0, 0, 1]]),
                   np.zeros(4)) for f in (1.0, 0.8, 1.25, 0.6, 1.6)]
    best, error = None, None
    for K0, D0 in starts:
        try:
            rms, K, D, rvecs, tvecs = cv2.fisheye.calibrate(
                obj, img, size, K0.copy(), D0.copy().reshape(4, 1),
                flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS, criteria=_CRITERIA)
        except cv2.error as e:
            error = e
            continue
        if np.isfinite(rms) and K[0, 0] > 0 and K[1, 1] > 0 and (best is None or rms < best[0]):
            best = (rms, K, np.asarray(D, dtype=np.float64).ravel(), rvecs, tvecs)
            if rms < GOOD_START_PX:
                break
    if best is None:
        raise error if error is not None else cv2.error('the fisheye calibration diverged')
    return best[1:]


def solve_view_pose(camera: CameraModel, view: BoardView) -> tuple[Array, Array]:
    """The board's pose in ``view`` with these intrinsics (iterative PnP on all corners)."""
    pts, K, D = camera.pnp_inputs(view.image_points)
    ok, rvec, tvec = cv2.solvePnP(view.object_points.reshape(-1, 1, 3), pts, K, D,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise _refusal(E.DEGENERATE_POINTS, f'view {view.name}: no pose with the '
                       'fitted intrinsics')
    return rvec.ravel(), tvec.ravel()


def _residuals(camera: CameraModel, view: BoardView, pose: tuple[Array, Array]) -> Array:
    return camera.project(view.object_points, *pose) - view.image_points


def _view_rms(camera: CameraModel, views, poses) -> dict[str, float]:
    return {v.name: float(np.sqrt(np.mean(np.sum(_residuals(camera, v, poses[v.name]) ** 2,
                                                 axis=1)))) for v in views}


def _rms(camera: CameraModel, views, poses) -> float:
    sq = np.concatenate([np.sum(_residuals(camera, v, poses[v.name]) ** 2, axis=1)
                         for v in views])
    return float(np.sqrt(np.mean(sq)))


def _heldout_rms(views: Sequence[BoardView], size, model: str, name: str,
                 fitted: CameraModel, folds: int) -> float:
    """RMS over every view of its error when it is held out: k-fold over the views (each
    fold's intrinsics fitted without it, from the full fit as the start), the held-out view's
    pose solved with those intrinsics. NaN when the views are too few to hold any out."""
    n = len(views)
    k = min(max(folds, 2), n)
    while k < n and n - -(-n // k) < MIN_VIEWS:
        k += 1
    if n - -(-n // k) < MIN_VIEWS:
        return float('nan')
    sq = []
    for fold in range(k):
        held = views[fold::k]
        train = [v for i, v in enumerate(views) if i % k != fold]
        camera, _ = _fit(train, size, model, name, guess=fitted)
        for v in held:
            sq.append(np.sum(_residuals(camera, v, solve_view_pose(camera, v)) ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(sq))))
