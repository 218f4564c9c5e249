"""Intrinsics on real board detections of another lab: OpenCV's multi-camera calibration test
data (test/data/opencv-multiview-3cams-hetero: one fisheye and two pinhole cameras, asymmetric
circle-grid centres), against an independent calibration of the same points written here: a
closed-form start (Zhang's homographies for the pinholes, the equidistant rays for the fisheye)
and a least-squares bundle adjustment over numpy projections and scipy, no OpenCV. Our fit
(core.landmarks.intrinsics, over OpenCV) must be the minimum that one finds: every intrinsic
within 1 % of its own standard deviation, the RMS equal. No figure of an earlier run is kept."""
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core.landmarks.intrinsics import BoardView, calibrate_intrinsics

DATA = Path(__file__).resolve().parents[2] / 'data' / 'opencv-multiview-3cams-hetero'
DISTORTION = {'plumb_bob': 5, 'rational_polynomial': 8, 'equidistant': 4}


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


# -- the independent calibration ---------------------------------------------------------------

def _homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """dst ~ H src by the normalised DLT; src, dst (N, 2)."""
    def conditioner(p):
        c = p.mean(axis=0)
        s = np.sqrt(2) / np.mean(np.linalg.norm(p - c, axis=1))
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])
    Ts, Td = conditioner(src), conditioner(dst)
    a = np.c_[src, np.ones(len(src))] @ Ts.T
    b = np.c_[dst, np.ones(len(dst))] @ Td.T
    zero = np.zeros_like(a)
    rows = np.r_[np.c_[zero, -b[:, 2:] * a, b[:, 1:2] * a],
                 np.c_[b[:, 2:] * a, zero, -b[:, :1] * a]]
    H = np.linalg.inv(Td) @ np.linalg.svd(rows)[2][-1].reshape(3, 3) @ Ts
    return H / H[2, 2]


def _zhang(Hs: list) -> np.ndarray:
    """K from three or more board homographies (Zhang 2000, section 3.1)."""
    def v(H, i, j):
        h = H.T
        return np.array([h[i, 0] * h[j, 0], h[i, 0] * h[j, 1] + h[i, 1] * h[j, 0],
                         h[i, 1] * h[j, 1], h[i, 2] * h[j, 0] + h[i, 0] * h[j, 2],
                         h[i, 2] * h[j, 1] + h[i, 1] * h[j, 2], h[i, 2] * h[j, 2]])
    V = np.array([row for H in Hs for row in (v(H, 0, 1), v(H, 0, 0) - v(H, 1, 1))])
    B11, B12, B22, B13, B23, B33 = np.linalg.svd(V)[2][-1]
    v0 = (B12 * B13 - B11 * B23) / (B11 * B22 - B12 ** 2)
    lam = B33 - (B13 ** 2 + v0 * (B12 * B13 - B11 * B23)) / B11
    fx, fy = np.sqrt(lam / B11), np.sqrt(lam * B11 / (B11 * B22 - B12 ** 2))
    return np.array([[fx, 0, -B13 * fx ** 2 / lam], [0, fy, v0], [0, 0, 1]])


def _pose(H: np.ndarray) -> np.ndarray:
    """(rotation vector, translation) of a board from its homography to the unit plane."""
    h1, h2, h3 = H.T
    scale = np.sign(h3[2]) / np.linalg.norm(h1)
    r1, r2 = scale * h1, scale * h2
    U, _, Vt = np.linalg.svd(np.c_[r1, r2, np.cross(r1, r2)])
    return np.r_[Rotation.from_matrix(U @ Vt).as_rotvec(), scale * h3]


def _project(model: str, k, d, P: np.ndarray) -> np.ndarray:
    """Pixels of camera-frame points P (N, 3): sensor_msgs/CameraInfo's models."""
    x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    if model == 'equidistant':
        r = np.hypot(x, y)
        theta = np.arctan(r)
        scale = theta * (1 + d[0] * theta ** 2 + d[1] * theta ** 4 + d[2] * theta ** 6
                         + d[3] * theta ** 8) / np.maximum(r, 1e-12)
        xd, yd = x * scale, y * scale
    else:
        r2 = x * x + y * y
        k1, k2, p1, p2, k3 = d[:5]
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        if len(d) == 8:
            radial = radial / (1 + d[5] * r2 + d[6] * r2 ** 2 + d[7] * r2 ** 3)
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.c_[k[0] * xd + k[2], k[1] * yd + k[3]]


def independent_calibration(views, size, model: str):
    """(fx fy cx cy and D, their standard deviations, RMS [px]) of a bundle adjustment of
    ``views`` from a closed-form start, without OpenCV."""
    w, h = size
    if model == 'equidistant':        # the rays of an undistorted equidistant camera
        f = max(w, h) / np.pi
        k0 = np.array([f, f, (w - 1) / 2, (h - 1) / 2])
        poses = []
        for v in views:
            u = (v.image_points - k0[2:]) / f
            theta = np.linalg.norm(u, axis=1)
            plane = u * (np.tan(theta) / np.maximum(theta, 1e-12))[:, None]
            poses.append(_pose(_homography(v.object_points[:, :2], plane)))
    else:
        Hs = [_homography(v.object_points[:, :2], v.image_points) for v in views]
        K = _zhang(Hs)
        k0 = K[[0, 1, 0, 1], [0, 1, 2, 2]]
        poses = [_pose(np.linalg.inv(K) @ H) for H in Hs]
    n = DISTORTION[model]
    which = np.concatenate([np.full(len(v.object_points), i) for i, v in enumerate(views)])
    obj = np.concatenate([v.object_points for v in views])
    img = np.concatenate([v.image_points for v in views])

    def residual(x):
        pose = x[4 + n:].reshape(-1, 6)[which]
        P = Rotation.from_rotvec(pose[:, :3]).apply(obj) + pose[:, 3:]
        return (_project(model, x[:4], x[4:4 + n], P) - img).ravel()

    sol = least_squares(residual, np.r_[k0, np.zeros(n), np.concatenate(poses)], method='lm',
                        x_scale='jac', xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=20000)
    dof = sol.jac.shape[0] - sol.jac.shape[1]
    std = np.sqrt(np.diag(np.linalg.pinv(sol.jac.T @ sol.jac)) * 2 * sol.cost / dof)
    rms = np.sqrt(np.mean(np.sum(sol.fun.reshape(-1, 2) ** 2, axis=1)))
    return sol.x[:4 + n], std[:4 + n], rms


@pytest.mark.parametrize('camera, size, model', [
    ('cam_7', (1920, 1080), 'plumb_bob'),
    ('cam_7', (1920, 1080), 'rational_polynomial'),
    ('cam_8', (1920, 1080), 'plumb_bob'),
    ('cam_8', (1920, 1080), 'rational_polynomial'),
    ('cam_4', (2048, 2048), 'equidistant'),
])
def test_the_fit_is_the_minimum_an_independent_calibration_finds(camera, size, model):
    """Measured: every intrinsic within 0.006 sigma of the independent one (rational k1..k6
    the farthest), RMS equal to 1e-8 relative."""
    views = _views(camera)
    fit = calibrate_intrinsics(views, size, model, name=camera)
    reference, std, rms = independent_calibration(views, size, model)
    K = fit.camera.K
    mine = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], fit.camera.D]
    assert fit.outlier_views == ()
    assert np.all(np.abs(mine - reference) < 0.01 * std), (mine - reference) / std
    assert fit.rms_px == pytest.approx(rms, rel=1e-6)
    assert fit.rms_px < fit.heldout_rms_px       # held out is never better than the fit


def test_the_fisheye_camera_is_a_fisheye():
    """cam_4 (the readme: a fisheye on the floor, 2048 x 2048) seen as one: an equidistant
    focal length whose field of view across the sensor passes 180 deg (f < width / pi), the
    principal point within 1 % of the sensor's width from its centre; the pinholes beside it
    see less than 90 deg."""
    fit = calibrate_intrinsics(_views('cam_4'), (2048, 2048), 'equidistant')
    K = fit.camera.K
    assert len(fit.camera.D) == 4
    assert np.degrees(2048 / K[0, 0]) > 180 and np.degrees(2048 / K[1, 1]) > 180
    assert np.hypot(K[0, 2] - 1023.5, K[1, 2] - 1023.5) < 0.01 * 2048
    pinhole = calibrate_intrinsics(_views('cam_7'), (1920, 1080), 'plumb_bob').camera.K
    assert np.degrees(2 * np.arctan(960 / pinhole[0, 0])) < 90
    # 12 of the 127 frames, none in the top-right: held out 1.41 px against the fit's 0.44 px
    assert 'held-out RMS' in fit.gate_problem
