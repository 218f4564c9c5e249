"""Intrinsics on real board detections of another lab: OpenCV's multi-camera calibration test
data (test/data/opencv-multiview-3cams-hetero: one fisheye and two pinhole cameras, asymmetric
circle-grid centres). Our fit's reprojection RMS equals OpenCV's own calibration of the same
points (called here directly) to 1 %, and the values measured when this test was written."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from cobot_calib_ros.core.landmarks.intrinsics import BoardView, calibrate_intrinsics

DATA = Path(__file__).resolve().parents[2] / 'data' / 'opencv-multiview-3cams-hetero'


def _board() -> np.ndarray:
    """OpenCV's genAsymmetricObjectPoints(Size(8, 11), 0.04) of the test that uses the data."""
    return np.array([[(2 * j + i % 2) * 0.04, i * 0.04, 0.0]
                     for i in range(11) for j in range(8)])


def _views(camera: str) -> list[BoardView]:
    fs = cv2.FileStorage(str(DATA / f'{camera}.json'), cv2.FILE_STORAGE_READ)
    try:
        return [BoardView(name, _board(), fs.getNode(name).mat().reshape(-1, 2))
                for name in fs.root().keys()]
    finally:
        fs.release()


def _opencv_pinhole_rms(views, size, flags) -> float:
    obj = [v.object_points.astype(np.float32) for v in views]
    img = [v.image_points.astype(np.float32) for v in views]
    return cv2.calibrateCamera(obj, img, size, None, None, flags=flags)[0]


def _opencv_fisheye_rms(views, size) -> float:
    # OpenCV's start (f = max(w, h) / pi, centre) given explicitly: cv2.fisheye.calibrate's
    # internal initialisation diverges on these 12 views (548 px with OpenCV 5.0)
    f = max(size) / np.pi
    K = np.array([[f, 0, (size[0] - 1) / 2], [0, f, (size[1] - 1) / 2], [0, 0, 1]])
    return cv2.fisheye.calibrate(
        [v.object_points.reshape(1, -1, 3) for v in views],
        [v.image_points.reshape(1, -1, 2) for v in views], size, K, np.zeros((4, 1)),
        flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW |
        cv2.CALIB_USE_INTRINSIC_GUESS)[0]


@pytest.mark.parametrize('camera, size, model, measured_rms', [
    ('cam_7', (1920, 1080), 'plumb_bob', 0.37039),
    ('cam_7', (1920, 1080), 'rational_polynomial', 0.16668),
    ('cam_8', (1920, 1080), 'plumb_bob', 0.19233),
    ('cam_8', (1920, 1080), 'rational_polynomial', 0.18184),
    ('cam_4', (2048, 2048), 'equidistant', 0.43837),
])
def test_rms_equals_opencvs_on_real_detections(camera, size, model, measured_rms):
    views = _views(camera)
    fit = calibrate_intrinsics(views, size, model, name=camera)
    if model == 'equidistant':
        reference = _opencv_fisheye_rms(views, size)
    else:
        flags = cv2.CALIB_RATIONAL_MODEL if model == 'rational_polynomial' else 0
        reference = _opencv_pinhole_rms(views, size, flags)
    assert fit.outlier_views == ()
    assert fit.rms_px == pytest.approx(reference, rel=0.01)
    assert fit.rms_px == pytest.approx(measured_rms, abs=2e-4)
    assert fit.rms_px < fit.heldout_rms_px       # held out is never better than the fit


def test_the_fisheye_camera_is_a_fisheye():
    """cam_4's equidistant intrinsics (the readme: a fisheye on the floor, 2048 x 2048):
    its focal length and principal point as measured, the centre near the image's."""
    fit = calibrate_intrinsics(_views('cam_4'), (2048, 2048), 'equidistant')
    K = fit.camera.K
    np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
                               [547.05, 546.63, 1014.85, 1025.60], atol=0.05)
    assert len(fit.camera.D) == 4
    # 12 of the 127 frames, none in the top-right: held out 1.41 px against the fit's 0.44 px
    assert 'held-out RMS' in fit.gate_problem
