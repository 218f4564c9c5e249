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

The procedures (issue 39.2): :func:`calibrate_planned` (plan, take, fit), :func:`calibrate_live`
(take the live views, fit) and :func:`calibrate_images` (a folder's or a bag's images, fit):
each an :class:`IntrinsicsRun` or a core.errors.Failure. Writing the camera_info YAML,
storing and activating are api.intrinsics's.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.core.landmarks.detect import BoardFinder
from cobot_calib_ros.core.landmarks.intrinsics import (BoardView, calibrate_intrinsics, Coverage,
                                                       image_coverage, IntrinsicsFit,
                                                       MIN_POINTS, solve_view_pose)
from cobot_calib_ros.core.landmarks.intrinsics_views import (board_view, detect_views,
                                                             intrinsics_views)
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.core.robot_port import (CaptureFailed, Cancelled, check_cancel, MoveFailed,
                                             never, port_failure, PortError, RobotPort,
                                             Stopped)

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


# views kept so far, views wanted, the coverage of the image and of tilts so far (judged with
# the nominal intrinsics)
Progress = Callable[[int, int, Coverage], None]
Views = tuple[list[BoardView], list[tuple[str, str]], tuple[int, int]]


@dataclass(frozen=True)
class IntrinsicsRun:
    """A fit and the views it came from; ``skipped``: (view name, why) of the others."""

    fit: IntrinsicsFit
    views: list[BoardView]
    skipped: list[tuple[str, str]]


def fit_views(views: Sequence[BoardView], skipped: list[tuple[str, str]],
              size: tuple[int, int], model: str, name: str) -> IntrinsicsRun | Failure:
    """calibrate_intrinsics of ``views``; its refusal as a Failure."""
    try:
        return IntrinsicsRun(calibrate_intrinsics(views, size, model, name=name), list(views),
                             skipped)
    except Refusal as e:
        return e.failure


def _coverage_of(nominal, count: int, progress: Progress | None) -> ViewDone | None:
    """A take_* on_view telling ``progress`` the views and coverage (poses solved with the
    ``nominal`` camera)."""
    if progress is None:
        return None

    def on_view(_, views, skipped) -> None:
        poses = {v.name: solve_view_pose(nominal, v) for v in views}
        progress(len(views), count, image_coverage(views, poses, (nominal.width,
                                                                  nominal.height)))
    return on_view


def _fitted(take: Callable[[], Views], model: str, name: str) -> IntrinsicsRun | Failure:
    """Take the views (a port error, a cancel: its Failure), then fit them; a refusal says how
    many views were skipped."""
    try:
        views, skipped, size = take()
    except Stopped as e:
        return port_failure(e, '; nothing stored')
    except PortError as e:
        return port_failure(e)
    except Refusal as e:
        return e.failure
    run = fit_views(views, skipped, size, model, name)
    if not run:
        return Failure(run.code, f'{run.message} ({len(skipped)} views skipped)')
    return run


def calibrate_planned(cell, kinematic_model, robot: RobotPort, images: ImagePort, *,
                      count: int, T_base_user, model: str, seed: int = 0,
                      image_timeout: float = IMAGE_TIMEOUT, cancelled: Cancelled = never,
                      progress: Progress | None = None) -> IntrinsicsRun | Failure:
    """The cell's camera moved by the arm through ``count`` planned views of its board (where
    ``T_base_user`` puts it; intrinsics_views on ``kinematic_model``'s nominal chain), then
    fitted with ``model``. Failures: INVALID_INPUT (no view plan), CAPTURE_FAILED, CANCELED,
    and the fit's (TOO_FEW_POINTS, DEGENERATE_POINTS, INVALID_INPUT)."""
    try:
        plan = intrinsics_views(cell, kinematic_model, count, seed, T_base_user=T_base_user)
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    spec = BoardSpec.parse(cell.landmarks.board)
    on_view = _coverage_of(cell.camera.camera_model(), count, progress)
    return _fitted(lambda: take_intrinsics_views(plan, robot, images, spec, cancelled=cancelled,
                                                 on_view=on_view,
                                                 image_timeout=image_timeout),
                   model, cell.camera.frame_id)


def calibrate_live(cell, images: ImagePort, *, count: int, deadline: Callable[[], bool],
                   model: str, image_timeout: float = IMAGE_TIMEOUT,
                   cancelled: Cancelled = never,
                   progress: Progress | None = None) -> IntrinsicsRun | Failure:
    """The cell's camera's live images while the user moves the board (or the camera): up to
    ``count`` new views until ``deadline()``, then fitted with ``model``. Failures as
    :func:`calibrate_planned`."""
    spec = BoardSpec.parse(cell.landmarks.board)
    on_view = _coverage_of(cell.camera.camera_model(), count, progress)
    return _fitted(lambda: take_live_views(images, spec, count, deadline=deadline,
                                           cancelled=cancelled, on_view=on_view,
                                           image_timeout=image_timeout),
                   model, cell.camera.frame_id)


def calibrate_images(images: Iterable[tuple[str, np.ndarray | None]], spec: BoardSpec, *,
                     model: str, name: str, source: str = 'the source'
                     ) -> IntrinsicsRun | Failure:
    """Images read from a folder or a bag ((name, mono8 or None: unreadable)) fitted with
    ``model``; INVALID_INPUT when there are none."""
    def take() -> Views:
        views, skipped, size = detect_views(images, spec)
        if size is None:
            raise Refusal(Failure(ErrorCode.INVALID_INPUT, f'{source}: no images'))
        return views, skipped, size
    return _fitted(take, model, name)
