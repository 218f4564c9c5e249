"""Hand-eye calibration of a wrist camera ("eye in hand") from views of a fixed board.

Unknowns: ``T_flange_optical`` X (the optical frame on the flange) and ``T_base_board`` B (the
board in the robot base). Every view i gives the flange pose ``T_base_flange`` F_i (joints
through the kinematic model) and the board pose ``T_optical_board`` M_i (PnP), and ideally
F_i X M_i = B. :func:`solve_hand_eye` starts from Park and Martin's closed form (AX = XB on
the relative motions; OpenCV's CALIB_HAND_EYE_PARK: OpenCV 5's Python bindings lack
calibrateHandEye), then refines X and B together by least squares on the board-pose residuals
of all views (position [m] and a left rotation [rad] in the optical frame, the convention of
core.landmarks.pose's covariances), and gives the 6x6 covariance of X from the Jacobian.

:func:`hand_eye_views` plans the views: the camera 0.25-0.45 m from the board centre, its view
axis tilted 10-35 deg from the board normal at azimuths spread around it, rotated about the
view axis, the whole board inside the image; joints by IK on the nominal chain to the camera
pose through the nominal hand-eye. Pure: numpy, scipy, OpenCV; no rclpy, messages or sim.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import Rotation
from cobot_calib_ros.core.kinematics.ik import solve_ik_with_restarts

Array = NDArray[np.float64]
MIN_VIEWS = 3
DISTANCE_RANGE = (0.25, 0.45)        # camera to board centre [m]
TILT_RANGE_DEG = (10.0, 35.0)        # view axis against the board normal [deg]
ROLL_RANGE_DEG = (-35.0, 35.0)       # rotation about the view axis [deg]
IMAGE_MARGIN_PX = 20.0               # the board's outer corners at least this far inside
MAX_ATTEMPTS_PER_VIEW = 200
# Rotation spread below which the views cannot fix the hand-eye: the second singular value of
# the stacked relative rotation vectors over the first [1] (all rotations about one axis).
MIN_AXIS_SPREAD = 0.02
MIN_ROTATION = 0.02                  # [rad] smallest relative rotation that counts
DEFAULT_SIGMA_M = 1e-4               # board-pose weights without covariances [m]
DEFAULT_SIGMA_RAD = 1e-3             # [rad]


@dataclass(frozen=True, eq=False)
class HandEyeResult:
    """``T_flange_optical``, ``T_base_board`` (4, 4) [m]; ``residual_m``/``residual_rad``:
    RMS over the views of the board-position and board-rotation residual; ``residuals_m``/
    ``residuals_rad`` per view; ``covariance`` (6, 6) of T_flange_optical over (x y z rx ry
    rz) [m, rad], the rotation a left perturbation in the flange frame; ``initial``: OpenCV's
    closed-form (Park) T_flange_optical; ``method``: its name. A solve that cannot give one
    returns a core.errors.Failure instead."""

    T_flange_optical: Array
    T_base_board: Array
    residual_m: float
    residual_rad: float
    residuals_m: Array
    residuals_rad: Array
    covariance: Array
    initial: Array
    method: str
    n_views: int
    nfev: int


def _board_centre(board_size: tuple[float, float]) -> Array:
    return np.array([board_size[0] / 2.0, board_size[1] / 2.0, 0.0])


def _turn(a: Array, b: Array) -> Array:
    """Smallest rotation taking unit vector a onto unit vector b."""
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        return np.eye(3) if c > 0 else Rotation.from_rotvec(
            math.pi * np.array([1.0, 0.0, 0.0])).as_matrix()
    return Rotation.from_rotvec(axis / s * math.atan2(s, c)).as_matrix()


def view_pose(T_base_board: Array, board_size: tuple[float, float], distance: float,
              tilt: float, azimuth: float, roll: float) -> Array:
    """T_base_optical [m] looking at the board centre from ``distance`` [m], the view axis
    tilted by ``tilt`` [rad] from the board's face normal towards ``azimuth`` [rad, about the
    normal, from the board's x axis], rotated by ``roll`` [rad] about the view axis. At zero
    tilt and roll the optical x axis is the board's x and optical z its z (into the board)."""
    R_bb = T_base_board[:3, :3]
    centre = frames.apply(T_base_board, _board_centre(board_size))
    # Board z points into the board: the camera is on the -z side.
    up = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth),
                   -math.cos(tilt)])
    u = R_bb @ up                                   # board centre -> camera, base frame
    R0 = R_bb                                       # optical frame = board frame, looking along +z
    R = _turn(R0[:, 2], -u) @ R0 @ frames.rot_z(roll)
    return frames.make_transform(R, centre + distance * u)


def board_in_image(T_optical_board: Array, board_size: tuple[float, float], camera,
                   margin: float = IMAGE_MARGIN_PX) -> bool:
    """True when the board's four outer corners project inside the image (``camera``: a
    core.landmarks.camera.CameraModel with width/height) with ``margin`` [px]."""
    w, h = board_size
    corners = np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0]], dtype=float)
    pts = frames.apply(T_optical_board, corners)
    if np.any(pts[:, 2] <= 0.05):
        return False
    rvec = cv2.Rodrigues(T_optical_board[:3, :3])[0]
    px, _ = cv2.projectPoints(corners, rvec, T_optical_board[:3, 3], np.asarray(camera.K),
                              np.asarray(camera.D))
    px = px.reshape(-1, 2)
    return bool(np.all(px[:, 0] >= margin) and np.all(px[:, 0] <= camera.width - 1 - margin)
                and np.all(px[:, 1] >= margin) and np.all(px[:, 1] <= camera.height - 1 - margin))


def board_view_setup(cell, model, T_base_user: ArrayLike,
                     T_flange_optical: ArrayLike | None = None) -> tuple:
    """What planning views of the cell's board starts from: (the board's size, T_base_board,
    the nominal chain ending at the camera (``T_flange_optical``, default the cell's nominal
    hand-eye), the camera model). ValueError if the cell has no camera or board."""
    if cell.camera is None or cell.landmarks is None or not cell.landmarks.board:
        raise ValueError(f'cell {cell.name!r} has no wrist camera or no board; add camera: '
                         'and landmarks: board: to the cell file')
    from cobot_calib_ros.core.landmarks.targets import BoardSpec
    size = BoardSpec.parse(cell.landmarks.board).size
    T_base_board = np.asarray(T_base_user, dtype=float) @ cell.landmarks.T_user_board()
    if T_flange_optical is None:
        T_flange_optical = cell.camera.T_flange_optical
    return (size, T_base_board, model.chain(tool=np.asarray(T_flange_optical, dtype=float)),
            cell.camera.camera_model())


def hand_eye_views(cell, model, count: int = 12, seed: int = 0, *,
                   T_base_user: ArrayLike | None = None,
                   T_flange_optical: ArrayLike | None = None) -> list[Array]:
    """``count`` joint configurations [rad] whose (nominal) camera sees the cell's board from
    different angles: distance, tilt and roll drawn from DISTANCE_RANGE, TILT_RANGE_DEG and
    ROLL_RANGE_DEG, azimuths spread evenly around the board with jitter; each has the whole
    board inside the image and an IK solution within the joint limits on the nominal chain
    (``model``'s nominal parameters, camera at ``T_flange_optical``, default the cell's nominal
    hand-eye). ``T_base_user``: where the user frame (the table) is in base, e.g. the active
    user-frame calibration (required: the cell file does not say). A view with none at its
    planned azimuth is drawn from any (:func:`reachable_view`). ValueError if the cell has no
    camera or board, or a view cannot be found (naming it and the limit), before any motion."""
    if cell.camera is None or cell.landmarks is None or not cell.landmarks.board:
        raise ValueError(f'cell {cell.name!r} has no wrist camera or no board; add camera: '
                         'and landmarks: board: to the cell file')
    if T_base_user is None:
        raise ValueError('hand_eye_views needs T_base_user: where the table (user frame) is '
                         'in the base frame')
    if count < MIN_VIEWS:
        raise ValueError(f'count must be at least {MIN_VIEWS}, got {count}')
    size, T_base_board, chain, camera = board_view_setup(cell, model, T_base_user,
                                                         T_flange_optical)
    rng = np.random.default_rng(seed)
    home = np.asarray(cell.home, dtype=float)
    views: list[Array] = []
    for k in range(count):
        def draw(anywhere: bool) -> Array:
            spread = rng.uniform(0.0, count) if anywhere else k + rng.uniform(-0.3, 0.3)
            azimuth = 2.0 * math.pi * spread / count
            tilt = math.radians(rng.uniform(*TILT_RANGE_DEG))
            roll = math.radians(rng.uniform(*ROLL_RANGE_DEG))
            distance = rng.uniform(*DISTANCE_RANGE)
            return view_pose(T_base_board, size, distance, tilt, azimuth, roll)
        views.append(reachable_view(draw, T_base_board, size, camera, chain,
                                    views[-1] if views else home, home,
                                    f'view {k + 1} of {count}'))
    return views


def reachable_view(draw: Callable[[bool], Array], T_base_board: Array,
                   board_size: tuple[float, float], camera, chain, seed_q: Array, home: Array,
                   label: str, margin_px: float = IMAGE_MARGIN_PX) -> Array:
    """Joints [rad] of the first camera pose ``draw`` gives (``draw(False)``: one as planned;
    ``draw(True)``: from anywhere around the board, tried once MAX_ATTEMPTS_PER_VIEW planned
    ones failed) that has the whole board in the image and an inverse kinematics solution of
    ``chain`` within the joint limits (solved from ``seed_q``, then ``home``), checked before
    the robot moves. ValueError naming ``label`` and the last pose's limit when no pose of
    2 x MAX_ATTEMPTS_PER_VIEW can be taken."""
    problem = 'the board was never inside the image'
    for attempt in range(2 * MAX_ATTEMPTS_PER_VIEW):
        T = draw(attempt >= MAX_ATTEMPTS_PER_VIEW)
        if not board_in_image(frames.invert(T) @ T_base_board, board_size, camera, margin_px):
            continue
        ik = solve_ik_with_restarts(chain, T, seed_q, home)
        if ik:
            return np.asarray(ik.q, dtype=float)
        problem = (f'camera at {np.round(T[:3, 3], 3).tolist()} m in the base: '
                   f'{ik.message}')
    raise ValueError(f'no reachable view of the board found for {label} in '
                     f'{2 * MAX_ATTEMPTS_PER_VIEW} attempts, from the planned azimuth and '
                     f'then from any; the last: {problem}; check the board placement, '
                     'T_base_user and the camera in the cell file')


# -- solver ---------------------------------------------------------------------------------

def _as_transforms(poses: Sequence[ArrayLike], name: str) -> Array:
    T = np.asarray(poses, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f'{name} must be a list of finite 4x4 transforms, got shape {T.shape}')
    return T


def check_rotation_spread(T_base_flange: Array) -> Failure | None:
    """A Failure (DEGENERATE_POINTS) when the flange rotations do not determine a hand-eye:
    fewer than two distinct rotation axes among the motions between views; else None."""
    vecs = []
    for i in range(len(T_base_flange)):
        for j in range(i + 1, len(T_base_flange)):
            rel = T_base_flange[i][:3, :3].T @ T_base_flange[j][:3, :3]
            v = Rotation.from_matrix(rel).as_rotvec()
            if np.linalg.norm(v) >= MIN_ROTATION:
                vecs.append(v / np.linalg.norm(v))
    if len(vecs) < 2:
        return Failure(ErrorCode.DEGENERATE_POINTS, (
            'degenerate views: the flange hardly rotates between them; the hand-eye needs '
            'rotations about at least two different axes'))
    s = np.linalg.svd(np.array(vecs), compute_uv=False)
    if s[1] < MIN_AXIS_SPREAD * s[0]:
        return Failure(ErrorCode.DEGENERATE_POINTS, (
            'degenerate views: every rotation between them is about one axis (axis spread '
            f'{s[1] / s[0]:.2g} < {MIN_AXIS_SPREAD}); tilt the camera about different axes'))
    return None


def _mean_transform(Ts: Array) -> Array:
    R = Rotation.from_matrix(Ts[:, :3, :3]).mean().as_matrix()
    return frames.make_transform(R, Ts[:, :3, 3].mean(axis=0))


def _perturb(T0: Array, d: Array) -> Array:
    """exp(d) applied on the left for the rotation, added for the translation."""
    return frames.make_transform(Rotation.from_rotvec(d[3:]).as_matrix() @ T0[:3, :3],
                                 T0[:3, 3] + d[:3])


def _errors(X: Array, B: Array, F: Array, M: Array) -> tuple[Array, Array]:
    """Per view: predicted minus measured board position in the optical frame (m, 3) [m] and
    the left rotation from measured to predicted (m, 3) [rad]."""
    P = np.linalg.inv(X) @ np.linalg.inv(F) @ B                      # predicted T_optical_board
    dp = P[:, :3, 3] - M[:, :3, 3]
    dr = Rotation.from_matrix(P[:, :3, :3] @ np.transpose(M[:, :3, :3], (0, 2, 1))).as_rotvec()
    return dp, dr


def _whiteners(covariances, n: int) -> Array:
    if covariances is None:
        W = np.diag([1.0 / DEFAULT_SIGMA_M] * 3 + [1.0 / DEFAULT_SIGMA_RAD] * 3)
        return np.repeat(W[None], n, axis=0)
    C = np.asarray(covariances, dtype=float)
    if C.shape != (n, 6, 6) or not np.all(np.isfinite(C)):
        raise ValueError(f'covariances must be {n} finite 6x6 matrices, got shape {C.shape}')
    out = np.empty_like(C)
    default = np.diag([1.0 / DEFAULT_SIGMA_M] * 3 + [1.0 / DEFAULT_SIGMA_RAD] * 3)
    for i, c in enumerate(C):
        try:                    # W^T W = C^-1; a singular (unfilled) covariance: the default
            out[i] = np.linalg.cholesky(np.linalg.inv(0.5 * (c + c.T))).T
        except np.linalg.LinAlgError:
            out[i] = default
    return out


def park_martin(F: Array, M: Array) -> Array:
    """Closed-form T_flange_optical from AX = XB over every pair of views (Park and Martin
    1994: the rotation by the orthogonal Procrustes fit of the motions' rotation vectors, then
    the translation by linear least squares); OpenCV 5's Python bindings lack
    calibrateHandEye, and this is its CALIB_HAND_EYE_PARK."""
    i, j = np.triu_indices(len(F), 1)                    # every pair of views
    A = np.linalg.inv(F)[i] @ F[j]                       # flange motions
    Bm = M[i] @ np.linalg.inv(M)[j]                      # camera motions
    alphas = Rotation.from_matrix(A[:, :3, :3]).as_rotvec()
    betas = Rotation.from_matrix(Bm[:, :3, :3]).as_rotvec()
    R = frames.kabsch_rotation(betas, alphas)            # alpha = R beta
    rows = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (Bm[:, :3, 3] @ R.T - A[:, :3, 3]).ravel()
    t = np.linalg.lstsq(rows, rhs, rcond=None)[0]
    return frames.make_transform(R, t)


def solve_hand_eye(T_base_flange: Sequence[ArrayLike], T_optical_board: Sequence[ArrayLike], *,
                   covariances: Sequence[ArrayLike] | None = None,
                   method: str = 'park') -> HandEyeResult | Failure:
    """T_flange_optical and T_base_board from matched flange and board poses (module
    docstring). ``covariances``: the board poses' 6x6 (landmark_detector's) to weight the
    views, default 0.1 mm / 1 mrad per axis; ``method``: the closed-form start, park.
    Every problem is a Failure, never raised: fewer than three views (TOO_FEW_POINTS),
    degenerate rotations (DEGENERATE_POINTS), mismatched or malformed lists and an unknown
    method (INVALID_INPUT), a solver that fails numerically (SOLVER_FAILED)."""
    try:
        F = _as_transforms(T_base_flange, 'T_base_flange')
        M = _as_transforms(T_optical_board, 'T_optical_board')
        if len(F) != len(M):
            raise ValueError(f'{len(F)} flange poses but {len(M)} board poses')
        if method != 'park':
            raise ValueError(f'unknown method {method!r}; use park')
        W = _whiteners(covariances, len(F))
    except ValueError as e:
        return Failure(ErrorCode.INVALID_INPUT, str(e))
    try:
        return _solve(F, M, W, method)
    except (ValueError, np.linalg.LinAlgError) as e:
        return Failure(ErrorCode.SOLVER_FAILED, (
            f'the hand-eye solver failed numerically ({e}); check the views for NaN or '
            'impossible poses'))


def _solve(F: Array, M: Array, W: Array, method: str) -> HandEyeResult | Failure:
    # X is T_flange_optical and B T_base_board, the paper's symbols (F_i X M_i = B, AX = XB);
    # only this solver and its helpers use them
    if len(F) < MIN_VIEWS:
        return Failure(ErrorCode.TOO_FEW_POINTS, (
            f'hand-eye calibration needs at least {MIN_VIEWS} views, got {len(F)}; take more '
            'views of the board'))
    degenerate = check_rotation_spread(F)
    if degenerate is not None:
        return degenerate
    X0 = park_martin(F, M)
    B0 = _mean_transform(F @ X0 @ M)

    def residual(d: Array, Xs: Array, Bs: Array) -> Array:
        dp, dr = _errors(_perturb(Xs, d[:6]), _perturb(Bs, d[6:]), F, M)
        return np.einsum('nij,nj->ni', W, np.hstack([dp, dr])).ravel()

    from scipy.optimize import least_squares    # here: importing it takes 0.3 s
    nfev = 0
    X, B = X0, B0
    for _ in range(2):           # the second pass re-bases at the solution: jac at d = 0
        sol = least_squares(residual, np.zeros(12), args=(X, B), method='lm', xtol=1e-15,
                            ftol=1e-15, gtol=1e-15, max_nfev=2000, x_scale=np.r_[
                                [1e-3] * 3, [1e-2] * 3, [1e-3] * 3, [1e-2] * 3])
        X, B = _perturb(X, sol.x[:6]), _perturb(B, sol.x[6:])
        nfev += sol.nfev
    J = sol.jac
    dof = J.shape[0] - J.shape[1]
    scale = float(2.0 * sol.cost / dof) if dof > 0 else 1.0
    try:
        cov = np.linalg.pinv(J.T @ J) * scale
    except np.linalg.LinAlgError:
        cov = np.full((12, 12), np.nan)
    # X's perturbation: translation added in the flange frame, rotation on the left in the
    # flange frame: the same as (x y z rx ry rz) of T_flange_optical.
    dp, dr = _errors(X, B, F, M)
    pos = np.linalg.norm(dp, axis=1)
    rot = np.linalg.norm(dr, axis=1)
    return HandEyeResult(
        T_flange_optical=X, T_base_board=B,
        residual_m=float(np.sqrt(np.mean(pos ** 2))),
        residual_rad=float(np.sqrt(np.mean(rot ** 2))), residuals_m=pos, residuals_rad=rot,
        covariance=cov[:6, :6], initial=X0, method=method, n_views=len(F), nfev=nfev)


# -- the gate before a hand-eye becomes active ----------------------------------------------

# How far the residual may exceed what the views' own noise explains before a result is
# refused [1]. Measured in-process on the mock Sawyer (test/core/landmarks/
# test_hand_eye_capture.py, 6-20 views, five seeds): right results 0.34-0.50 (the detector's
# covariances are conservative; the nominal model's kinematic error is inside); images of the
# arm at the previous view in 3 of 12 views (issue 22.9): 294 (residual 39.9 mm). Exact
# covariances on synthetic poses: 0.81-1.29; one image 2.6 mm / 10.8 mrad early: 10.6-24.6.
# With covariances that fit, RMS / expected beyond 1.4 has odds below 1e-3 at 60 residuals.
MAX_NOISE_RATIO = 3.0


@dataclass(frozen=True)
class NoiseCheck:
    """The residual against what the views' board-pose covariances explain: ``expected_m``/
    ``expected_rad`` the RMS residual that noise alone would leave (the same statistic as
    HandEyeResult.residual_m/_rad), ``ratio`` the larger of residual / expected [1];
    ``problem`` '' when the ratio is within ``max_ratio``, else why the result must not be
    made active."""

    expected_m: float
    expected_rad: float
    ratio: float
    max_ratio: float
    problem: str

    def __bool__(self) -> bool:
        return not self.problem


def check_noise(result: HandEyeResult, covariances: Sequence[ArrayLike],
                max_ratio: float = MAX_NOISE_RATIO) -> NoiseCheck:
    """Does ``result`` fit its views as well as their noise allows? ``covariances``: the views'
    board-pose 6x6 covariances [m, rad] (landmark_detector's), in the order solved. The noise
    alone leaves E|dp_i|^2 = trace(C_i, position) (1 - 12 / 6n) at the solution (12 unknowns,
    6n residuals), likewise the rotation; a residual RMS beyond ``max_ratio`` times that means
    views that do not belong together (an image of another pose than its joints), not noise."""
    C = np.asarray(covariances, dtype=float)
    if C.shape != (result.n_views, 6, 6) or not np.all(np.isfinite(C)):
        raise ValueError(f'covariances must be {result.n_views} finite 6x6 matrices, got '
                         f'shape {C.shape}')
    kept = max(1.0 - 12.0 / (6.0 * result.n_views), 1e-3)
    pos = np.trace(C[:, :3, :3], axis1=1, axis2=2)
    rot = np.trace(C[:, 3:, 3:], axis1=1, axis2=2)
    expected_m = float(np.sqrt(np.mean(pos) * kept))
    expected_rad = float(np.sqrt(np.mean(rot) * kept))
    if expected_m <= 0.0 or expected_rad <= 0.0:
        raise ValueError('covariances must be positive definite: no noise to compare with')
    ratio = max(result.residual_m / expected_m, result.residual_rad / expected_rad)
    problem = '' if ratio <= max_ratio else (
        f'residual RMS {result.residual_m * 1e3:.3f} mm / {result.residual_rad * 1e3:.3f} mrad '
        f'is {ratio:.1f}x what the views\' noise leaves ({expected_m * 1e3:.3f} mm / '
        f'{expected_rad * 1e3:.3f} mrad; at most {max_ratio:g}x): some views do not fit the '
        'others '
        '(an image of another pose than its joints, a board that moved); repeat the '
        'calibration on a quiet machine and check that the robot rests at every view')
    return NoiseCheck(expected_m, expected_rad, ratio, max_ratio, problem)
