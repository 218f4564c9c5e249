"""The views of an intrinsics calibration taken on the cell: move, wait for an image, detect
the board (a procedure over the robot port and an image port).

For each planned joint configuration (core.landmarks.intrinsics_views.intrinsics_views) the
robot moves there; the first image stamped after the move returned is searched for the board
(detect.BoardFinder, the project's ChArUco detector). A view that is unreachable or shows too
few corners is skipped and named; ``cancelled()`` is checked before every view (Stopped).
``on_view(index, views, skipped)`` after each one (coverage feedback). Runs the same over ROS
(RobotCalls and ros.image_watch.ImageWatch) and in-process on the simulation (DirectRobot,
sim.camera.DirectImages).

Live (take_live_views): no robot; the user moves the board (or the camera) and every image is
searched; one becomes a view when it differs from every view kept (MIN_VIEW_SHIFT_PX), until
``count`` views or the time is up.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.landmarks.detect import BoardFinder
from cobot_calib_ros.core.landmarks.intrinsics import BoardView, MIN_POINTS
from cobot_calib_ros.core.landmarks.intrinsics_views import board_view
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.core.robot_port import (CaptureFailed, Cancelled, check_cancel, MoveFailed,
                                             never, RobotPort)

IMAGE_TIMEOUT = 5.0          # [s] for an image after the arm came to rest
# live views (the user moves the board): an image is a new view when its corners moved at
# least this far [px] (mean over the corners both see) from every view kept, or it shows
# fewer than half of the corners of each of them in common
MIN_VIEW_SHIFT_PX = 25.0


class ImagePort(Protocol):
    """Raw images of the camera: ``now_ns`` its clock; ``image_after(t_ns, timeout)`` the first
    (stamp [ns], mono8) stamped after ``t_ns`` (CaptureFailed after ``timeout`` [s])."""

    def now_ns(self) -> int: ...
    def image_after(self, t_ns: int, timeout: float) -> tuple[int, NDArray[np.uint8]]: ...


ViewDone = Callable[[int, list[BoardView], list[tuple[str, str]]], None]


def take_intrinsics_views(plan: Sequence[NDArray], robot: RobotPort, images: ImagePort,
                          spec: BoardSpec, *, cancelled: Cancelled = never,
                          on_view: ViewDone | None = None, image_timeout: float = IMAGE_TIMEOUT
                          ) -> tuple[list[BoardView], list[tuple[str, str]], tuple[int, int]]:
    """(views, skipped [(view name, why)], image size (width, height)) of the planned views.
    A view is named 'view<i>' (its index in ``plan``). CaptureFailed when no image comes."""
    finder = BoardFinder(spec)
    views: list[BoardView] = []
    skipped: list[tuple[str, str]] = []
    size = (0, 0)
    for i, q in enumerate(plan):
        name = f'view{i}'
        check_cancel(cancelled, f'view {i + 1} of {len(plan)}')
        try:
            robot.move_joints(q)
        except MoveFailed as e:
            skipped.append((name, f'not reached: {e}'))
        else:
            _, gray = images.image_after(images.now_ns(), image_timeout)
            size = (gray.shape[1], gray.shape[0])
            view = board_view(name, finder.finish(finder.find(gray)), spec)
            if view is None:
                skipped.append((name, f'fewer than {MIN_POINTS} board corners seen'))
            else:
                views.append(view)
        if on_view is not None:
            on_view(i, views, skipped)
    if size == (0, 0):
        raise CaptureFailed('no view was reached: no image taken')
    return views, skipped, size


def is_new_view(view: BoardView, kept: Sequence[BoardView],
                min_shift_px: float = MIN_VIEW_SHIFT_PX) -> bool:
    """True when ``view``'s corners moved at least ``min_shift_px`` (mean over the corners in
    common) from every view of ``kept``, or it has fewer than half its corners in common with
    it (another part of the board)."""
    for other in kept:
        ours = {tuple(p): i for i, p in enumerate(np.round(view.object_points, 9))}
        pairs = [(ours[tuple(p)], j) for j, p in enumerate(np.round(other.object_points, 9))
                 if tuple(p) in ours]
        if len(pairs) < len(view.object_points) / 2:
            continue
        a, b = (np.array(idx) for idx in zip(*pairs))
        shift = np.linalg.norm(view.image_points[a] - other.image_points[b], axis=1).mean()
        if shift < min_shift_px:
            return False
    return True


def take_live_views(images: ImagePort, spec: BoardSpec, count: int, *, deadline: Callable[[],
                    bool], cancelled: Cancelled = never, on_view: ViewDone | None = None,
                    image_timeout: float = IMAGE_TIMEOUT,
                    min_shift_px: float = MIN_VIEW_SHIFT_PX
                    ) -> tuple[list[BoardView], list[tuple[str, str]], tuple[int, int]]:
    """(views, skipped, image size) from the live images: each image after the previous one
    is searched; a new view (is_new_view) is kept, named by its stamp, until ``count`` views or
    ``deadline()`` is True. ``on_view(images seen, views, skipped)`` after each kept view.
    CaptureFailed when no image comes within ``image_timeout``."""
    finder = BoardFinder(spec)
    views: list[BoardView] = []
    skipped: list[tuple[str, str]] = []
    size, after, seen = (0, 0), images.now_ns(), 0
    while len(views) < count and not deadline():
        check_cancel(cancelled, f'{len(views)} of {count} views')
        after, gray = images.image_after(after, image_timeout)
        seen += 1
        size = (gray.shape[1], gray.shape[0])
        view = board_view(str(after), finder.finish(finder.find(gray)), spec)
        if view is not None and is_new_view(view, views, min_shift_px):
            views.append(view)
            if on_view is not None:
                on_view(seen, views, skipped)
    return views, skipped, size
