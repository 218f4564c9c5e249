"""core.landmarks.detect for a live camera: MarkerFinder / BoardFinder (built once, used for many
images, find and finish on different threads) give what detect_markers / detect_board give, and
the saddle-point refinement, which smooths only windows around the points, gives what smoothing
the whole image gives, also at the image's edges.
"""
import threading

import cv2
import numpy as np
import pytest

from cobot_calib_ros.core.landmarks import detect
from cobot_calib_ros.core.landmarks.detect import (BoardFinder, detect_board, detect_markers,
                                                   MarkerFinder, refine_saddle_points)
from test_pose import (board_texture, BOARD, CAMERA, FACING_CAMERA, marker_texture, MARKER_DICT,
                       random_pose, render)


def _images(texture, base, n, seed):
    rng = np.random.default_rng(seed)
    tex, plane = texture
    return [render(tex, plane, random_pose(rng, base=base), noise=2.0, rng=rng)
            for _ in range(n)]


@pytest.mark.parametrize('refine', ['edges', 'subpix', 'none'])
def test_a_reused_marker_finder_gives_what_detect_markers_gives(refine):
    images = _images(marker_texture(), FACING_CAMERA, 4, 11)
    finder = MarkerFinder(MARKER_DICT, refine=refine)
    found = [finder.find(image) for image in images]          # all searched, then finished
    for image, result in zip(images, found):
        expected = detect_markers(image, MARKER_DICT, refine=refine, camera=CAMERA)
        got = finder.finish(result, CAMERA)
        assert [m.id for m in got] == [m.id for m in expected] == [7]
        assert np.array_equal(got[0].corners, expected[0].corners)


def test_a_reused_board_finder_gives_what_detect_board_gives_across_threads():
    images = _images(board_texture(), np.eye(3), 4, 12)
    finder = BoardFinder(BOARD, refine='subpix')
    found = [None] * len(images)

    def search():
        for i, image in enumerate(images):
            found[i] = finder.find(image)

    thread = threading.Thread(target=search)
    thread.start()
    thread.join()
    for image, result in zip(images, found):
        expected = detect_board(image, BOARD, refine='subpix', camera=CAMERA)
        got = finder.finish(result, CAMERA)
        assert len(got) == len(expected) >= 4
        assert np.array_equal(got.charuco_ids, expected.charuco_ids)
        assert np.array_equal(got.charuco_corners, expected.charuco_corners)


def _chessboard(noise_seed=None):
    """A blurred chessboard (square 20 px), its inner corners [px] and some points 1-3 px from
    the image's edges."""
    square = 20
    y, x = np.mgrid[0:300, 0:400]    # large enough for windows (few points: the whole image)
    board = (((x + 7) // square + (y + 3) // square) % 2 * 200 + 30).astype(np.float64)
    if noise_seed is not None:
        board += np.random.default_rng(noise_seed).normal(0.0, 8.0, board.shape)
    gray = cv2.GaussianBlur(np.clip(board, 0, 255).astype(np.uint8), (0, 0), 1.0)
    corners = np.array([[13.0 + i * square, 17.0 + j * square] for i in range(7)
                        for j in range(5)]) - 0.5
    edges = np.array([[0.6, 1.2], [398.7, 298.6], [2.2, 76.5], [80.4, 0.1], [399.4, 150.3]])
    return gray, corners, edges


@pytest.mark.parametrize('radius', [2, 4, 6])
def test_saddle_windows_read_the_whole_image_smoothed_also_at_the_edges(radius):
    gray, corners, edges = _chessboard(noise_seed=radius)
    points = np.vstack([corners + [0.3, -0.4], edges])
    sigma = max(0.7, radius / 3.0)
    reach = 2 * radius + 2
    tiles, origin = detect._smoothed_windows(gray, points, reach, sigma)
    whole = cv2.GaussianBlur(gray.astype(np.float32), (0, 0), sigma)
    pad = 3 * reach
    whole = cv2.copyMakeBorder(whole, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
    for (px, py), (ox, oy) in zip(np.rint(points).astype(int), origin.astype(int)):
        ys, xs = np.mgrid[py - reach:py + reach + 2, px - reach:px + reach + 2]
        read = cv2.remap(tiles, (xs - ox).astype(np.float32), (ys - oy).astype(np.float32),
                         cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)   # as refined
        assert np.abs(read - whole[ys + pad, xs + pad]).max() < 1e-3


@pytest.mark.parametrize('radius', [2, 4, 6])
def test_saddle_points_are_found_also_near_the_edges(radius):
    gray, corners, edges = _chessboard()
    got, ok = refine_saddle_points(gray, np.vstack([corners + [0.3, -0.4], edges]), radius)
    assert ok[:len(corners)].all()
    assert np.abs(got[:len(corners)] - corners).max() < 0.05


def test_the_fast_search_finds_the_markers_the_full_search_finds_with_the_same_corners():
    """search_parameters (ArUco 3: candidates on a scaled-down image, ~3x faster at 1280x800 in
    the node) gives the same markers and 'edges' corners; a marker smaller than the fraction
    asked for is not searched."""
    images = _images(marker_texture(), FACING_CAMERA, 4, 13)
    fast = MarkerFinder(MARKER_DICT, refine='edges', params=detect.search_parameters(0.02))
    for image in images:
        expected = detect_markers(image, MARKER_DICT, refine='edges', camera=CAMERA)
        got = fast.finish(fast.find(image), CAMERA)
        assert [m.id for m in got] == [m.id for m in expected] == [7]
        assert np.abs(got[0].corners - expected[0].corners).max() < 0.01       # [px]
    side = np.linalg.norm(np.diff(expected[0].corners, axis=0), axis=1).max()
    too_small = detect.search_parameters(1.5 * side / max(image.shape))
    assert MarkerFinder(MARKER_DICT, params=too_small).finish(
        MarkerFinder(MARKER_DICT, params=too_small).find(image)) == []
    assert detect.search_parameters(0.0) is None
