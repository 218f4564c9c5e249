"""The landmark search of one image, as landmark_detector and `cobot-calib detect` both run it:
single markers of a dictionary and a ChArUco board, each posed where a camera (and, for the
markers, their side length) is known; the board's own markers (``board_ids``) are listed but not
posed as single markers.

Two halves, so a node can release the GIL for OpenCV's searches and keep its own thread for
the rest: ``find`` (the searches) and ``finish`` (refinement and poses). The OpenCV detectors
are built once; ``find`` on one thread at a time.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.detect import (BoardDetection, BoardFinder, DEFAULT_REFINE,
                                                   MarkerDetection, MarkerFinder)
from cobot_calib_ros.core.landmarks.pose import (estimate_board_pose, estimate_marker_pose,
                                                 PoseEstimate)
from cobot_calib_ros.core.landmarks.targets import BoardSpec


@dataclass(frozen=True)
class Detections:
    """What one image showed: each marker with its pose (None where it is not posed: one of
    the board's, no camera or side length, or the estimate failed, see ``pose_errors``) and
    the board with its pose."""

    markers: list[tuple[MarkerDetection, PoseEstimate | None]] = field(default_factory=list)
    board: BoardDetection | None = None
    board_pose: PoseEstimate | None = None
    pose_errors: dict = field(default_factory=dict)   # marker id or 'board': why not posed


class Pipeline:
    """``dictionary``: the single markers' (None: none); ``board``: the ChArUco board (None:
    none); ``marker_length`` [m]: the single markers' side (None: not posed); ``refine``: the
    markers' corner refinement, ``board_refine`` the board markers' (default the same);
    ``params``: detector parameters of the markers' search (detect.search_parameters)."""

    def __init__(self, dictionary: str | None, board: BoardSpec | None, *,
                 marker_length: float | None = None, refine: str = DEFAULT_REFINE,
                 board_refine: str | None = None, params=None) -> None:
        self.board_spec, self.marker_length = board, marker_length
        self._markers = None if dictionary is None else MarkerFinder(
            dictionary, refine=refine, params=params)
        self._board = None if board is None else BoardFinder(
            board, refine=refine if board_refine is None else board_refine)
        self.board_ids = frozenset() if board is None or board.dictionary != dictionary else \
            frozenset(range(board.first_id, board.first_id + board.n_markers))

    def find(self, image) -> tuple:
        return (None if self._markers is None else self._markers.find(image),
                None if self._board is None else self._board.find(image))

    def finish(self, found: tuple, camera: CameraModel | None) -> Detections:
        markers_found, board_found = found
        out = Detections()
        if markers_found is not None:
            for marker in self._markers.finish(markers_found, camera):
                pose = None
                if (camera is not None and self.marker_length is not None
                        and marker.id not in self.board_ids):
                    pose = estimate_marker_pose(marker.corners, self.marker_length, camera)
                    if not pose:
                        out.pose_errors[marker.id], pose = pose.message, None
                out.markers.append((marker, pose))
        if board_found is not None:
            board = self._board.finish(board_found, camera)
            pose = None
            if camera is not None:
                pose = estimate_board_pose(board, self.board_spec, camera)
                if not pose:
                    out.pose_errors['board'], pose = pose.message, None
            out = Detections(out.markers, board, pose, out.pose_errors)
        return out

    def detect(self, image, camera: CameraModel | None) -> Detections:
        return self.finish(self.find(image), camera)

