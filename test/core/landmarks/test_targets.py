"""Dictionaries by name, ChArUco board specs, and detection's input checks."""
import cv2
import numpy as np
import pytest

from cobot_calib_ros.core.landmarks.detect import (ImageError, detect_board, detect_markers,
                                                   detector_parameters, refine_corners_edges)
from cobot_calib_ros.core.landmarks.targets import (BoardSpec, canonical_dictionary_name,
                                                    dictionary_names, get_dictionary)


@pytest.mark.parametrize('name, canonical', [
    ('DICT_4X4_50', 'DICT_4X4_50'), ('dict_6x6_250', 'DICT_6X6_250'), ('6x6_250', 'DICT_6X6_250'),
    ('DICT_APRILTAG_36h11', 'DICT_APRILTAG_36H11'), ('apriltag_36h11', 'DICT_APRILTAG_36H11'),
    ('DICT_ARUCO_ORIGINAL', 'DICT_ARUCO_ORIGINAL')])
def test_dictionary_names_are_case_insensitive(name, canonical):
    assert canonical_dictionary_name(name) == canonical
    assert get_dictionary(name).markerSize == get_dictionary(canonical).markerSize


def test_every_predefined_dictionary_once():
    names = dictionary_names()
    assert len(names) == len(set(names)) == 22
    assert 'DICT_APRILTAG_36H11' in names and 'DICT_APRILTAG_36h11' not in names


def test_unknown_dictionary_lists_close_names():
    with pytest.raises(ValueError, match=r"unknown marker dictionary 'DICT_6X6_25'; did you "
                                         r"mean DICT_6X6_250"):
        canonical_dictionary_name('DICT_6X6_25')
    with pytest.raises(ValueError, match='known: DICT_4X4_100'):
        canonical_dictionary_name('qwerty')


def test_board_spec_parses_and_prints_back():
    spec = BoardSpec.parse('ChArUco: squares=5x7, square=0.04, marker=0.02, dict=dict_6x6_250')
    assert spec == BoardSpec(5, 7, 0.04, 0.02, 'DICT_6X6_250')
    assert str(spec) == 'charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250'
    assert BoardSpec.parse(str(spec)) == spec
    legacy = BoardSpec.parse('charuco:squares=6x6,square=0.03,marker=0.02,dict=DICT_4X4_50,'
                             'legacy=1,first=10')
    assert legacy.legacy and legacy.first_id == 10 and legacy.board().getLegacyPattern()
    assert list(legacy.board().getIds().ravel()) == list(range(10, 28))
    assert BoardSpec.parse(str(legacy)) == legacy
    assert (spec.n_markers, spec.n_corners, spec.size) == (17, 24, (0.2, 0.28))


def test_board_frame_corners_are_opencvs():
    spec = BoardSpec(5, 7, 0.04, 0.02, 'DICT_6X6_250')
    np.testing.assert_allclose(spec.corner_points(), spec.board().getChessboardCorners(),
                               atol=1e-7)


@pytest.mark.parametrize('text, words', [
    ('squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250', 'must start with "charuco:"'),
    ('charuco:squares=5x7,square=0.04,dict=DICT_6X6_250', 'lacks marker'),
    ('charuco:squares=5,square=0.04,marker=0.02,dict=DICT_6X6_250', 'COLUMNSxROWS'),
    ('charuco:squares=5x7,square=40,marker=20,dict=DICT_6X6_250', 'lengths are metres'),
    ('charuco:squares=5x7,square=0.02,marker=0.04,dict=DICT_6X6_250', 'marker (0.04) < square'),
    ('charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250,colour=red', 'KEY=VALUE'),
    ('charuco:squares=12x12,square=0.04,marker=0.02,dict=DICT_4X4_50', 'needs 72 marker ids'),
    ('charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_9X9_1', 'unknown marker dictionary'),
])
def test_bad_board_specs_say_what_is_wrong(text, words):
    with pytest.raises(ValueError) as e:
        BoardSpec.parse(text)
    assert words in str(e.value)


@pytest.mark.parametrize('image, words', [
    (np.zeros((0, 0), np.uint8), 'empty'),
    (np.zeros((10, 10), np.float32), 'float32; expected uint8'),
    (np.zeros((10, 10), np.uint16), 'uint16'),
    (np.zeros((10, 10, 2), np.uint8), 'shape (10, 10, 2)'),
    (None, 'expected a numpy image array'),
    ([[0, 1], [2, 3]], 'expected a numpy image array'),
])
def test_bad_images_are_refused_clearly(image, words):
    for detect in (lambda i: detect_markers(i, 'DICT_4X4_50'),
                   lambda i: detect_board(i, BoardSpec(3, 3, 0.04, 0.03, 'DICT_4X4_50'))):
        with pytest.raises(ImageError) as e:
            detect(image)
        assert words in str(e.value)


def test_accepted_image_layouts_and_nothing_found():
    d = get_dictionary('DICT_4X4_50')
    marker = cv2.copyMakeBorder(cv2.aruco.generateImageMarker(d, 3, 120), 60, 60, 60, 60,
                                cv2.BORDER_CONSTANT, value=255)
    for image in (marker, marker[:, :, None], cv2.cvtColor(marker, cv2.COLOR_GRAY2BGR),
                  cv2.cvtColor(marker, cv2.COLOR_GRAY2BGRA)):
        found = detect_markers(image, 'DICT_4X4_50')
        assert [m.id for m in found] == [3]
        # the black square spans pixels 60..179: its edges at 59.5 and 179.5
        np.testing.assert_allclose(found[0].corners, [[59.5, 59.5], [179.5, 59.5],
                                                      [179.5, 179.5], [59.5, 179.5]], atol=0.02)
        np.testing.assert_allclose(found[0].center, [119.5, 119.5], atol=0.02)
    assert detect_markers(np.full((50, 60), 255, np.uint8), 'DICT_4X4_50') == []
    empty = detect_board(np.full((50, 60), 255, np.uint8), BoardSpec(3, 3, 0.04, 0.03,
                                                                     'DICT_4X4_50'))
    assert len(empty) == 0 and empty.charuco_corners.shape == (0, 2)


def test_detector_parameters():
    p = detector_parameters('apriltag', {'minMarkerDistanceRate': 0.05})
    assert p.cornerRefinementMethod == cv2.aruco.CORNER_REFINE_APRILTAG
    assert p.minMarkerDistanceRate == pytest.approx(0.05)
    with pytest.raises(ValueError, match="unknown detector parameter 'nope'"):
        detector_parameters('subpix', {'nope': 1})
    with pytest.raises(ValueError, match='unknown corner refinement'):
        detector_parameters('magic')


def _marker_120px(size=(240, 240), at=(60, 60)) -> tuple[np.ndarray, np.ndarray]:
    """DICT_4X4_50 id 3, its black square 120 px wide from pixel ``at``: (image, true corners)."""
    image = np.full(size, 255, np.uint8)
    x, y = at
    image[y:y + 120, x:x + 120] = cv2.aruco.generateImageMarker(get_dictionary('DICT_4X4_50'),
                                                                3, 120)
    truth = np.array([[x - 0.5, y - 0.5], [x + 119.5, y - 0.5], [x + 119.5, y + 119.5],
                      [x - 0.5, y + 119.5]])
    return image, truth


def test_edges_refine_more_markers_than_cv2_remap_takes_rows():
    """200 markers x 4 sides x 48 profiles exceed cv2.remap's 32767 rows (e6ccb73 crashed on the
    400-marker industrial_calibration photo): they are sampled in batches, every one fitted."""
    image, truth = _marker_120px()
    start = np.repeat((truth + [0.4, -0.3])[None], 200, axis=0)
    corners, fitted = refine_corners_edges(image, start, 6)
    assert fitted.all()
    np.testing.assert_allclose(corners, np.repeat(truth[None], 200, axis=0), atol=0.02)


def test_edges_refine_a_marker_in_an_image_wider_than_cv2_remap_takes():
    """A 33000 px wide image (cv2.remap takes < 32767): read through the crop around the marker."""
    image, truth = _marker_120px(size=(240, 33000), at=(32760, 60))
    corners, fitted = refine_corners_edges(image, (truth + [0.4, -0.3])[None], 6)
    assert fitted.all()
    np.testing.assert_allclose(corners[0], truth, atol=0.02)


def test_markers_edges_cannot_fit_keep_subpix_corners_and_say_so():
    """A 9 px marker (1.5 px per module, below EDGE_MIN_MODULE_PX once measured) keeps OpenCV's
    SUBPIX corners and says 'subpix'; the 120 px one is fitted."""
    image, truth = _marker_120px(size=(240, 400))
    d = get_dictionary('DICT_4X4_50')
    image[100:109, 300:309] = cv2.resize(cv2.aruco.generateImageMarker(d, 7, 600), (9, 9),
                                         interpolation=cv2.INTER_AREA)
    found = {m.id: m for m in detect_markers(image, 'DICT_4X4_50')}
    subpix = {m.id: m for m in detect_markers(image, 'DICT_4X4_50', refine='subpix')}
    assert {i: m.refinement for i, m in found.items()} == {3: 'edges', 7: 'subpix'}
    np.testing.assert_array_equal(found[7].corners, subpix[7].corners)
    np.testing.assert_allclose(found[3].corners, truth, atol=0.02)
    assert {m.refinement for m in subpix.values()} == {'subpix'}
