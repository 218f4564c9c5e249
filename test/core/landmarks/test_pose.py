"""Marker and board poses on synthetic images whose truth is exact.

A target texture (marker with a white margin, or a ChArUco board) is projected with a known pose
through cv2.warpPerspective at 3x resolution and area-downsampled (pixel centres at integer
coordinates, OpenCV's convention, in both images), seen by a 752x480 camera at 0.2-0.5 m.
Goals (issue 11): one 50 mm marker <= 0.8 mm / 0.1 deg, a ChArUco board <= 0.05 mm / 0.02 deg,
medians on clean images.
"""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import transform_error
from cobot_calib_ros.core.landmarks.camera import CameraModel
from cobot_calib_ros.core.landmarks.detect import BoardDetection, detect_board, detect_markers
from cobot_calib_ros.core.landmarks.pose import (AMBIGUITY_RATIO, estimate_board_pose,
                                                 estimate_marker_pose, estimate_pose)
from cobot_calib_ros.core.landmarks.targets import BoardSpec, get_dictionary, marker_object_points

W, H = 752, 480
K = np.array([[700.0, 0.0, 375.2], [0.0, 700.0, 241.3], [0.0, 0.0, 1.0]])
CAMERA = CameraModel(W, H, K, np.zeros(5))
SS = 3                         # supersampling
MARKER = 0.05                  # [m]
MARKER_DICT = 'DICT_6X6_250'
BOARD = BoardSpec.parse('charuco:squares=7x5,square=0.025,marker=0.018,dict=DICT_4X4_50')
FACING_CAMERA = np.diag([1.0, -1.0, -1.0])   # marker frame (y up, z out) seen from the front


# --- rendering ---------------------------------------------------------------------------
def marker_texture(marker_id: int = 7, cell_px: int = 50):
    """Marker image with a white margin of ceil(cells / 2) cells; texture -> marker plane."""
    d = get_dictionary(MARKER_DICT)
    cells = d.markerSize + 2
    side = cells * cell_px
    margin = (cells + 1) // 2 * cell_px
    tex = cv2.copyMakeBorder(cv2.aruco.generateImageMarker(d, marker_id, side, borderBits=1),
                             margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255)
    s, c = MARKER / side, margin - 0.5 + side / 2     # the marker's edge is at margin - 0.5
    return tex, np.array([[s, 0, -c * s], [0, -s, c * s], [0, 0, 1]])


def board_texture(spec: BoardSpec = BOARD, square_px: int = 100):
    """Board image, one square of margin; texture -> board plane (origin top-left corner)."""
    size = (spec.squares_x * square_px + 2 * square_px, spec.squares_y * square_px + 2 * square_px)
    tex = spec.board().generateImage(size, marginSize=square_px, borderBits=1)
    s, o = spec.square_length / square_px, square_px - 0.5
    return tex, np.array([[s, 0, -o * s], [0, s, -o * s], [0, 0, 1]])


def render(texture, plane_map, T, noise=0.0, rng=None):
    """mono8 image of the textured plane z = 0 of a frame posed at T_optical_target."""
    hi_res = np.array([[SS, 0, (SS - 1) / 2], [0, SS, (SS - 1) / 2], [0, 0, 1]]) @ K
    homography = hi_res @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ plane_map
    hi = cv2.warpPerspective(texture, homography, (W * SS, H * SS), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    image = cv2.resize(hi, (W, H), interpolation=cv2.INTER_AREA)
    if noise:
        image = np.clip(image + rng.normal(0.0, noise, image.shape), 0, 255).astype(np.uint8)
    return image


def random_pose(rng, base=np.eye(3), centre=(0.0, 0.0), z=(0.2, 0.5), max_tilt_deg=40.0):
    """Target at 0.2-0.5 m, tilted up to max_tilt_deg, any roll, its centre in mid image."""
    axis = np.r_[rng.normal(size=2), 0.0]
    tilt = np.deg2rad(rng.uniform(0.0, max_tilt_deg)) * axis / np.linalg.norm(axis)
    R = Rotation.from_rotvec(tilt).as_matrix() @ base @ \
        Rotation.from_rotvec([0.0, 0.0, rng.uniform(-np.pi, np.pi)]).as_matrix()
    ray = np.linalg.inv(K) @ [rng.uniform(0.35, 0.65) * W, rng.uniform(0.35, 0.65) * H, 1.0]
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = ray * rng.uniform(*z) - R @ np.r_[centre, 0.0]
    return T


def _errors(poses):
    e = np.array([(t * 1e3, np.degrees(r)) for t, r in poses])
    return np.median(e, axis=0), e.max(axis=0)


# --- accuracy ----------------------------------------------------------------------------
@pytest.mark.parametrize('refine', [
    'edges',
    pytest.param('subpix', marks=pytest.mark.xfail(
        strict=True, reason='measured median 0.55 mm / 0.28 deg (max 2.2 mm / 1.2 deg): '
                            'cornerSubPix pulls the L-shaped marker corners ~0.19 px inward')),
])
def test_one_50mm_marker_pose_meets_the_goal(refine):
    rng = np.random.default_rng(1)
    texture, plane_map = marker_texture()
    poses, ratios = [], []
    for _ in range(24):
        T = random_pose(rng, base=FACING_CAMERA)
        found = detect_markers(render(texture, plane_map, T), MARKER_DICT, refine=refine)
        assert [m.id for m in found] == [7]
        pose = estimate_marker_pose(found[0].corners, MARKER, CAMERA)
        assert pose, pose
        poses.append(transform_error(pose.T_optical_target, T))
        ratios.append(pose.ambiguity_ratio)
    (t_med, r_med), (t_max, r_max) = _errors(poses)
    print(f'50 mm marker, refine {refine}: median {t_med:.3f} mm / {r_med:.3f} deg, '
          f'max {t_max:.3f} mm / {r_max:.3f} deg (goal 0.8 mm / 0.1 deg)')
    assert t_med <= 0.8 and r_med <= 0.1


def test_charuco_board_pose_meets_the_goal():
    rng = np.random.default_rng(2)
    texture, plane_map = board_texture()
    centre = np.array(BOARD.size) / 2
    poses, opencv_only, corner_err = [], [], []
    for _ in range(24):
        T = random_pose(rng, centre=centre)
        image = render(texture, plane_map, T)
        for saddle, out in ((True, poses), (False, opencv_only)):
            detection = detect_board(image, BOARD, saddle=saddle)
            assert len(detection) >= 6
            pose = estimate_board_pose(detection, BOARD, CAMERA)
            assert pose, pose
            out.append(transform_error(pose.T_optical_target, T))
            if saddle:
                truth = CAMERA.project(BOARD.corner_points()[detection.charuco_ids],
                                       cv2.Rodrigues(T[:3, :3])[0], T[:3, 3])
                corner_err.append(np.linalg.norm(detection.charuco_corners - truth, axis=1))
    (t_med, r_med), (t_max, r_max) = _errors(poses)
    (o_t, o_r), _ = _errors(opencv_only)
    print(f'ChArUco 7x5 x 25 mm: median {t_med:.4f} mm / {r_med:.4f} deg, max {t_max:.4f} mm / '
          f'{r_max:.4f} deg, corners {np.mean(np.concatenate(corner_err)):.4f} px '
          f'(OpenCV corners alone: median {o_t:.4f} mm / {o_r:.4f} deg; goal 0.05 mm / 0.02 deg)')
    assert t_med <= 0.05 and r_med <= 0.02


def test_edges_fit_in_the_undistorted_image_on_a_wide_angle_lens():
    """Barrel distortion bends a marker's sides; with the camera the lines are fitted where
    they are straight. Rendered through the lens model (remap), markers near the corners."""
    D = np.array([-0.32, 0.11, 0.0005, -0.0008, -0.016])
    camera = CameraModel(W, H, np.array([[420.0, 0, 376.0], [0, 420.0, 240.0], [0, 0, 1]]), D)
    ys, xs = np.mgrid[0:H * SS, 0:W * SS].astype(np.float64)
    ideal = camera.undistort_pixels(np.stack([(xs - 1) / SS, (ys - 1) / SS], -1).reshape(-1, 2))
    ideal = np.column_stack([ideal, np.ones(len(ideal))])
    length = 0.08
    texture, plane_map = marker_texture()
    plane_map = np.diag([length / MARKER, length / MARKER, 1.0]) @ plane_map
    rng = np.random.default_rng(0)
    errors = {'with camera': [], 'without': []}
    for u, v in ((150, 120), (600, 120), (150, 360), (600, 360)):
        R = Rotation.from_rotvec(rng.normal(0.0, 0.3, 3)).as_matrix() @ FACING_CAMERA
        ray = np.linalg.inv(camera.K) @ np.r_[camera.undistort_pixels([[u, v]])[0], 1.0]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, ray * rng.uniform(0.25, 0.4)
        homography = camera.K @ np.column_stack([R[:, 0], R[:, 1], T[:3, 3]]) @ plane_map
        tex_xy = ideal @ np.linalg.inv(homography).T
        tex_xy = (tex_xy[:, :2] / tex_xy[:, 2:]).astype(np.float32).reshape(H * SS, W * SS, 2)
        hi = cv2.remap(texture, tex_xy[..., 0], tex_xy[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=128)
        image = cv2.resize(hi, (W, H), interpolation=cv2.INTER_AREA)
        for name, cam in (('with camera', camera), ('without', None)):
            found = detect_markers(image, MARKER_DICT, camera=cam)
            assert len(found) == 1
            pose = estimate_marker_pose(found[0].corners, length, camera)
            errors[name].append(transform_error(pose.T_optical_target, T))
    (t_cam, r_cam), _ = _errors(errors['with camera'])
    (t_raw, r_raw), _ = _errors(errors['without'])
    print(f'80 mm marker, k1 = -0.32: edges with camera median {t_cam:.3f} mm / {r_cam:.3f} deg,'
          f' without {t_raw:.3f} mm / {r_raw:.3f} deg')
    assert t_cam <= 0.2 and r_cam <= 0.05 and t_cam < t_raw


# --- ambiguity, frames, covariance ---------------------------------------------------------
def test_mirror_ambiguity_is_rejected_on_an_oblique_view():
    texture, plane_map = marker_texture()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('x', 55, degrees=True).as_matrix() @ FACING_CAMERA
    T[:3, 3] = [0.02, -0.01, 0.45]
    found = detect_markers(render(texture, plane_map, T), MARKER_DICT)
    pose = estimate_marker_pose(found[0].corners, MARKER, CAMERA)
    t_err, r_err = transform_error(pose.T_optical_target, T)
    _, flip = transform_error(pose.alternative, T)
    print(f'55 deg oblique at 0.45 m: chosen {t_err * 1e3:.3f} mm / {np.degrees(r_err):.3f} deg; '
          f'mirror solution off by {np.degrees(flip):.1f} deg, reprojection ratio '
          f'{pose.ambiguity_ratio:.1f}')
    assert t_err < 1e-3 and np.degrees(r_err) < 0.2
    assert np.degrees(flip) > 20.0
    assert pose.ambiguity_ratio > AMBIGUITY_RATIO and not pose.ambiguous
    # the rejected one is IPPE's other solution, with the larger reprojection error
    assert pose.alternative_rms_px > pose.rms_px


def test_a_small_far_frontal_marker_is_flagged_ambiguous():
    rng = np.random.default_rng(4)
    obj = marker_object_points(0.02)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('x', 3, degrees=True).as_matrix() @ FACING_CAMERA
    T[:3, 3] = [0.0, 0.0, 1.5]
    pixels = CAMERA.project(obj, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3])
    ambiguous = [estimate_marker_pose(pixels + rng.normal(0, 0.3, pixels.shape), 0.02,
                                      CAMERA).ambiguous for _ in range(20)]
    assert np.mean(ambiguous) > 0.5


def test_frames_are_opencvs_marker_and_board_frames():
    """Marker: the first corner (top-left as printed) is at (-L/2, +L/2, 0): y up, z out of
    the face. Board: the first ChArUco corner is at (square, square, 0): y down, z in."""
    texture, plane_map = marker_texture()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = FACING_CAMERA, [0.0, 0.0, 0.3]
    found = detect_markers(render(texture, plane_map, T), MARKER_DICT)
    top_left = CAMERA.project([[-0.025, 0.025, 0.0]], cv2.Rodrigues(FACING_CAMERA)[0], T[:3, 3])
    np.testing.assert_allclose(found[0].corners[0], top_left[0], atol=0.05)
    pose = estimate_marker_pose(found[0].corners, MARKER, CAMERA)
    np.testing.assert_allclose(pose.T_optical_target[:3, :3], FACING_CAMERA, atol=2e-3)
    assert found[0].corners[0, 0] < found[0].corners[1, 0]   # TL left of TR
    assert found[0].corners[0, 1] < found[0].corners[3, 1]   # TL above BL
    btex, bmap = board_texture()
    T = np.eye(4)
    T[:3, 3] = [-0.08, -0.06, 0.35]
    detection = detect_board(render(btex, bmap, T), BOARD)
    pose = estimate_board_pose(detection, BOARD, CAMERA)
    np.testing.assert_allclose(pose.T_optical_target[:3, :3], np.eye(3), atol=1e-3)
    first = detection.charuco_corners[list(detection.charuco_ids).index(0)]
    np.testing.assert_allclose(first, CAMERA.project([[0.025, 0.025, 0.0]], np.zeros(3),
                                                     T[:3, 3])[0], atol=0.05)


def _left_perturbation(T_est, T_true):
    dR = T_est[:3, :3] @ T_true[:3, :3].T
    return np.r_[T_est[:3, 3] - T_true[:3, 3], Rotation.from_matrix(dR).as_rotvec()]


@pytest.mark.parametrize('target', ['marker', 'board'])
def test_covariance_is_positive_definite_and_matches_monte_carlo(target):
    """Noisy projections (0.3 px) of exact points: the spread of 400 solutions matches the
    predicted sigma^2 (J^T J)^-1 in (x y z, rotation about the optical axes)."""
    rng = np.random.default_rng(7)
    sigma = 0.3
    T = np.eye(4)
    if target == 'marker':
        T[:3, :3] = Rotation.from_rotvec([0.4, -0.3, 0.2]).as_matrix() @ FACING_CAMERA
        T[:3, 3] = [0.03, -0.02, 0.3]
        obj = marker_object_points(MARKER)
    else:
        T[:3, :3] = Rotation.from_rotvec([0.3, 0.25, 0.1]).as_matrix()
        T[:3, 3] = [-0.08, -0.05, 0.4]
        obj = BOARD.corner_points()
    clean = CAMERA.project(obj, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3])

    def solve(pixels):
        if target == 'marker':
            return estimate_marker_pose(pixels, MARKER, CAMERA, pixel_sigma=sigma)
        return estimate_pose(obj, pixels, CAMERA, pixel_sigma=sigma)

    predicted = solve(clean).covariance
    samples = np.array([_left_perturbation(solve(clean + rng.normal(0, sigma, clean.shape))
                                           .T_optical_target, T) for _ in range(400)])
    empirical = np.cov(samples.T)
    ratio = np.sqrt(np.diag(empirical) / np.diag(predicted))
    print(f'{target}: predicted sigma x y z [mm] {np.sqrt(np.diag(predicted)[:3]) * 1e3}, '
          f'rot [deg] {np.degrees(np.sqrt(np.diag(predicted)[3:]))}; empirical / predicted '
          f'{np.round(ratio, 2)}')
    assert np.all(np.linalg.eigvalsh(predicted) > 0)
    np.testing.assert_allclose(predicted, predicted.T)
    assert np.all((ratio > 0.8) & (ratio < 1.25))


def test_residual_sigma_and_its_floor():
    obj = BOARD.corner_points()
    T = np.eye(4)
    T[:3, 3] = [-0.08, -0.05, 0.4]
    clean = CAMERA.project(obj, np.zeros(3), T[:3, 3])
    assert estimate_pose(obj, clean, CAMERA).sigma_px == pytest.approx(0.1)   # exact fit: floor
    noisy = clean + np.random.default_rng(3).normal(0, 0.5, clean.shape)
    assert 0.4 < estimate_pose(obj, noisy, CAMERA).sigma_px < 0.6


def test_fisheye_camera_poses():
    camera = CameraModel(W, H, K, np.array([0.05, -0.01, 0.002, -0.0005]), 'equidistant')
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.2, -0.3, 0.1]).as_matrix()
    T[:3, 3] = [0.05, 0.02, 0.35]
    obj = BOARD.corner_points()
    pixels = camera.project(obj, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3])
    t_err, r_err = transform_error(estimate_pose(obj, pixels, camera).T_optical_target, T)
    assert t_err < 1e-7 and r_err < 1e-7
    np.testing.assert_allclose(camera.distort_pixels(camera.undistort_pixels(pixels)), pixels,
                               atol=1e-6)


# --- refusals ----------------------------------------------------------------------------
def test_pose_refusals_are_falsy_failures():
    square = np.array([[100.0, 100.0], [200.0, 100.0], [200.0, 200.0], [100.0, 200.0]])
    assert estimate_marker_pose(square, 0.05, CAMERA)
    for corners, length, code in [
        (square, 0.0, ErrorCode.INVALID_INPUT),
        (square[:3], 0.05, ErrorCode.INVALID_INPUT),
        (np.full((4, 2), np.nan), 0.05, ErrorCode.INVALID_INPUT),
        (np.repeat(square[:1], 4, axis=0), 0.05, ErrorCode.DEGENERATE_POINTS),
    ]:
        result = estimate_marker_pose(corners, length, CAMERA)
        assert not result and result.code == code, result
    few = BoardDetection(np.array([0, 1, 2]), np.zeros((3, 2)), ())
    assert estimate_board_pose(few, BOARD, CAMERA).code == ErrorCode.TOO_FEW_POINTS
    row = BoardDetection(np.array([0, 1, 2, 3, 4]), np.c_[np.arange(5) * 30.0 + 100, [200] * 5],
                         ())
    assert estimate_board_pose(row, BOARD, CAMERA).code == ErrorCode.DEGENERATE_POINTS
    outside = BoardDetection(np.array([0, 1, 2, 99]), np.zeros((4, 2)), ())
    assert estimate_board_pose(outside, BOARD, CAMERA).code == ErrorCode.INVALID_INPUT
