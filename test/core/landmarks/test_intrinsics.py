"""Intrinsics calibration (core.landmarks.intrinsics) on synthetic views of a known camera,
and the camera_info YAML writer against the one reader."""
import cv2
import numpy as np
import pytest

from cobot_calib_ros.core.landmarks.camera import (camera_info_yaml, CameraModel,
                                                   parse_camera_info)
from cobot_calib_ros.core.errors import ErrorCode, Refusal
from cobot_calib_ros.core.landmarks.intrinsics import BoardView, calibrate_intrinsics
from cobot_calib_ros.loaders import load_camera_info_yaml

SIZE = (1280, 800)
K_TRUE = np.array([[900.0, 0.0, 645.0], [0.0, 902.0, 395.0], [0.0, 0.0, 1.0]])
TRUTHS = {
    'plumb_bob': CameraModel(*SIZE, K_TRUE, [-0.25, 0.08, 0.0004, -0.0003, -0.01],
                             'plumb_bob'),
    'rational_polynomial': CameraModel(*SIZE, K_TRUE, [0.4, -0.1, 0.0003, 0.0002, 0.01,
                                                       0.7, -0.05, 0.02],
                                       'rational_polynomial'),
    'equidistant': CameraModel(*SIZE, K_TRUE, [0.05, -0.02, 0.01, -0.003], 'equidistant'),
}
BOARD = np.array([[x * 0.03, y * 0.03, 0.0] for y in range(7) for x in range(10)])
NOISE_PX = 0.05            # per coordinate


def _views(camera, n=24, seed=1, noise=NOISE_PX, tilt_deg=35.0, spread=1.0, depths=(0.35, 0.6)):
    """n views of BOARD whose centre is spread over the image, tilted about both axes."""
    rng = np.random.default_rng(seed)
    out = []
    centre = BOARD.mean(axis=0)
    while len(out) < n:
        ax, ay = np.radians(rng.uniform(-tilt_deg, tilt_deg, 2))
        R = cv2.Rodrigues(np.array([ax, ay, rng.uniform(-0.3, 0.3)]))[0]
        depth = rng.uniform(*depths)
        u, v = rng.uniform(0.1, 0.9, 2) * spread + (1 - spread) * 0.5
        ray = np.linalg.inv(camera.K) @ [u * SIZE[0], v * SIZE[1], 1.0]
        t = ray * depth - R @ centre
        px = camera.project(BOARD, cv2.Rodrigues(R)[0], t)
        if not ((px > 5).all() and (px[:, 0] < SIZE[0] - 5).all()
                and (px[:, 1] < SIZE[1] - 5).all()):
            continue
        out.append(BoardView(f'v{len(out)}', BOARD, px + rng.normal(0, noise, px.shape)))
    return out


@pytest.mark.parametrize('model', ['plumb_bob', 'rational_polynomial', 'equidistant'])
def test_recovers_the_true_camera_at_the_noise(model):
    truth = TRUTHS[model]
    fit = calibrate_intrinsics(_views(truth), SIZE, model, name='wrist')
    K = fit.camera.K
    assert abs(K[0, 0] / 900.0 - 1) < 1e-3 and abs(K[1, 1] / 902.0 - 1) < 1e-3
    assert abs(K[0, 2] - 645.0) < 0.5 and abs(K[1, 2] - 395.0) < 0.5
    assert fit.camera.distortion_model == model and fit.camera.name == 'wrist'
    assert len(fit.camera.D) == len(truth.D)
    # RMS of the pixel distance of noise sigma per coordinate: sigma sqrt(2), a little less
    # for the parameters fitted
    expected = NOISE_PX * np.sqrt(2)
    assert 0.85 * expected < fit.rms_px < 1.02 * expected
    assert fit.rms_px < fit.heldout_rms_px < 1.3 * fit.rms_px
    assert fit.outlier_views == () and fit.views_used == 24
    assert fit.coverage.complete and fit.coverage.fraction > 0.8
    assert fit.gate_problem == ''
    # the fitted lens sends the pixels where the views were along the true rays (0.5 px at
    # the true focal length: what the focal length's 0.1 % leaves at the edges)
    grid = np.stack(np.meshgrid(np.linspace(200, 1080, 9), np.linspace(150, 650, 7)),
                    -1).reshape(-1, 2)

    def rays(camera):
        return (camera.undistort_pixels(grid) - camera.K[:2, 2]) / np.diag(camera.K)[:2]
    np.testing.assert_allclose(rays(fit.camera) * 900.0, rays(truth) * 900.0, atol=0.5)


def test_an_outlier_view_is_named_dropped_and_the_fit_repeated():
    views = _views(TRUTHS['plumb_bob'], n=16)
    rng = np.random.default_rng(5)
    bad = views[7]
    views[7] = BoardView(bad.name, bad.object_points,
                         bad.image_points + rng.normal(0, 2.0, bad.image_points.shape))
    fit = calibrate_intrinsics(views, SIZE, 'plumb_bob')
    assert fit.outlier_views == ('v7',)
    assert fit.views_used == 15
    assert fit.view_rms_px['v7'] > 2.0 and fit.rms_px < 0.08
    assert abs(fit.camera.K[0, 0] / 900.0 - 1) < 1e-3


def test_too_few_views_are_refused():
    with pytest.raises(Refusal, match='3 views') as e:
        calibrate_intrinsics(_views(TRUTHS['plumb_bob'], n=3), SIZE, 'plumb_bob')
    assert e.value.failure.code == ErrorCode.TOO_FEW_POINTS


def test_fronto_parallel_views_are_refused():
    views = _views(TRUTHS['plumb_bob'], n=8, tilt_deg=1.0)
    with pytest.raises(Refusal, match='fronto-parallel') as e:
        calibrate_intrinsics(views, SIZE, 'plumb_bob')
    assert e.value.failure.code == ErrorCode.DEGENERATE_POINTS


def test_nan_points_are_refused():
    px = TRUTHS['plumb_bob'].project(BOARD, [0.3, 0.1, 0], [0, 0, 0.5])
    px[3, 0] = np.nan
    with pytest.raises(Refusal, match='not finite') as e:
        BoardView('frame_3', BOARD, px)
    assert e.value.failure.code == ErrorCode.INVALID_INPUT


def test_unknown_model_is_refused():
    with pytest.raises(Refusal, match='unknown model') as e:
        calibrate_intrinsics(_views(TRUTHS['plumb_bob'], n=5), SIZE, 'kannala')
    assert e.value.failure.code == ErrorCode.INVALID_INPUT


def test_coverage_names_the_missing_parts_and_fails_the_gate():
    # views bunched in the middle of the image, tilted only a little
    views = _views(TRUTHS['plumb_bob'], n=10, spread=0.15, tilt_deg=12.0, depths=(1.2, 1.4))
    fit = calibrate_intrinsics(views, SIZE, 'plumb_bob')
    cover = fit.coverage
    assert 'top-left' in cover.missing_regions and 'bottom-right' in cover.missing_regions
    assert 'centre' not in cover.missing_regions
    assert cover.fraction < 0.5
    assert 'missing: corners in the image' in cover.message
    assert 'corners cover' in fit.gate_problem and 'missing:' in fit.gate_problem


def test_camera_info_yaml_round_trip(tmp_path):
    for model, truth in TRUTHS.items():
        camera = CameraModel(truth.width, truth.height, truth.K, truth.D, model, 'wrist_cam')
        text = camera_info_yaml(camera)
        path = tmp_path / f'{model}.yaml'
        path.write_text(text)
        back = load_camera_info_yaml(path)
        assert (back.width, back.height, back.name, back.distortion_model) == \
            (1280, 800, 'wrist_cam', model)
        np.testing.assert_array_equal(back.K, camera.K)
        np.testing.assert_array_equal(back.D, camera.D)


def test_camera_info_yaml_has_camera_calibrations_layout():
    camera = CameraModel(640, 480, [[500.0, 0, 320.5], [0, 501.0, 240.5], [0, 0, 1]],
                         [0.1, -0.2, 0.0, 0.0, 0.0], 'plumb_bob', 'my camera')
    text = camera_info_yaml(camera)
    keys = [line.split(':')[0] for line in text.splitlines() if not line.startswith(' ')]
    assert keys == ['image_width', 'image_height', 'camera_name', 'camera_matrix',
                    'distortion_model', 'distortion_coefficients', 'rectification_matrix',
                    'projection_matrix']
    assert 'camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500.0, 0.0, 320.5,' in text
    assert 'distortion_coefficients:\n  rows: 1\n  cols: 5\n' in text
    assert 'projection_matrix:\n  rows: 3\n  cols: 4\n  data: [500.0, 0.0, 320.5, 0.0, ' in text
    assert parse_camera_info(text, 'x').name == 'my camera'     # quoted, read back
