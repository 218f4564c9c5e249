"""Views for an intrinsics calibration: arm poses that put the cell's ChArUco board over the
whole image at many tilts, and a board detection as a calibration view.

The poses are the hand-eye's (core.landmarks.hand_eye.view_pose: a distance, a tilt towards an
azimuth, a roll) with the camera then turned about its own centre so that the board's centre
lands on a target of a grid over the image (its corners and edges included), the whole board
still inside the image.
"""
from __future__ import annotations

from collections.abc import Iterable
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.landmarks.detect import BoardDetection, BoardFinder
from cobot_calib_ros.core.landmarks.hand_eye import (_turn, board_view_setup, reachable_view,
                                                     view_pose)
from cobot_calib_ros.core.landmarks.intrinsics import BoardView, MIN_POINTS
from cobot_calib_ros.core.landmarks.targets import BoardSpec

Array = NDArray[np.float64]
DISTANCE_RANGE = (0.40, 0.60)        # camera to board centre [m]
TILT_RANGE_DEG = (25.0, 50.0)        # view axis against the board normal [deg]
ROLL_RANGE_DEG = (-30.0, 30.0)
# where the board's centre is aimed, as fractions of the image (x, y): a 3 x 3 grid
AIM_FRACTIONS = (0.26, 0.5, 0.74)
IMAGE_MARGIN_PX = 8.0


def intrinsics_views(cell, model, count: int = 24, seed: int = 0, *,
                     T_base_user: ArrayLike, T_flange_optical: ArrayLike | None = None
                     ) -> list[Array]:
    """``count`` joint configurations [rad] whose nominal camera sees the cell's whole board,
    its centre aimed in turn at each cell of a 3 x 3 grid over the image, tilted towards
    azimuths spread around the board (so that every image region and tilt direction comes up);
    where no view at the planned azimuth is reachable, one from another azimuth
    (hand_eye.reachable_view). ValueError if the cell has no camera or board, or a view cannot
    be found (naming it and the joint limit), before anything moves."""
    size, T_base_board, chain, camera = board_view_setup(cell, model, T_base_user,
                                                         T_flange_optical)
    rng = np.random.default_rng(seed)
    home = np.asarray(cell.home, dtype=float)
    aims = [(fx, fy) for fy in AIM_FRACTIONS for fx in AIM_FRACTIONS]
    views: list[Array] = []
    for k in range(count):
        fx, fy = aims[k % len(aims)]
        aim = np.r_[camera.undistort_pixels([[fx * (camera.width - 1),
                                               fy * (camera.height - 1)]])[0], 1.0]
        aim = np.linalg.inv(camera.K) @ aim
        turn = _turn(np.array([0.0, 0.0, 1.0]), aim / np.linalg.norm(aim)).T

        def draw(anywhere: bool) -> Array:
            turns = rng.uniform(0.0, 1.0) if anywhere else k * 0.382 + rng.uniform(-0.1, 0.1)
            T = view_pose(T_base_board, size, rng.uniform(*DISTANCE_RANGE),     # golden steps
                          math.radians(rng.uniform(*TILT_RANGE_DEG)), 2.0 * math.pi * turns,
                          math.radians(rng.uniform(*ROLL_RANGE_DEG)))
            T[:3, :3] = T[:3, :3] @ turn
            return T
        views.append(reachable_view(
            draw, T_base_board, size, camera, chain, views[-1] if views else home, home,
            f'view {k + 1} of {count} (the board centre at {fx:.2f}, {fy:.2f} of the image)',
            IMAGE_MARGIN_PX))
    return views


def detect_views(images: Iterable[tuple[str, NDArray[np.uint8] | None]], spec: BoardSpec
                 ) -> tuple[list[BoardView], list[tuple[str, str]], tuple[int, int] | None]:
    """(views, skipped [(name, why)], image size (width, height)) of ``images`` ((name, mono8
    or None: unreadable)) through the project's ChArUco detector (detect.BoardFinder). Images of
    another size than the first are skipped."""
    finder = BoardFinder(spec)
    views, skipped, size = [], [], None
    for name, image in images:
        if image is None:
            skipped.append((name, 'not a readable image'))
            continue
        shape = (image.shape[1], image.shape[0])
        size = size or shape
        if shape != size:
            skipped.append((name, f'{shape[0]}x{shape[1]} px, the first image is '
                                  f'{size[0]}x{size[1]}'))
            continue
        detection = finder.finish(finder.find(image))
        view = board_view(name, detection, spec)
        if view is None:
            skipped.append((name, f'{len(detection)} board corners found, {MIN_POINTS} '
                                  f'needed ({len(detection.markers)} of its markers)'))
        else:
            views.append(view)
    return views, skipped, size


def board_view(name: str, detection: BoardDetection, spec: BoardSpec) -> BoardView | None:
    """The calibration view of a ChArUco detection (its corners at their board positions),
    None when it has fewer than MIN_POINTS corners."""
    if len(detection) < MIN_POINTS:
        return None
    return BoardView(name, spec.corner_points()[detection.charuco_ids],
                     detection.charuco_corners)
