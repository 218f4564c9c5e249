"""User-frame calibration from touched points: pure math, SI units (m, rad).

Inputs are ``p_user`` (N, 3), nominal marker positions in the user frame [m], and ``p_base``
(N, 3), the same markers measured in the robot base frame [m]. Every method returns a
:class:`FrameFit` that is falsy on failure (data problems are values; wrong shapes raise).

Methods (``METHODS``):

- ``three_point``: the paper's eqs 3-5 (section 2.1) on the first three points only.
- ``five_point_lsq``: the paper's eqs 6-8 (section 2.2): the 12-parameter affine ``M`` by least
  squares. On a coplanar user layout (all z = 0, as in the paper) ``A`` has rank 3 and ``M``'s
  column along the plane normal is unobservable; it is completed from the two in-plane columns.
- ``rigid`` (default): Kabsch/Umeyama SVD fit without scale, reflection guarded.
- ``robust``: the rigid fit with leave-one-out rejection of gross outliers.

Pose covariance convention, all methods: the 6-vector (x, y, z, rx, ry, rz) perturbs the fit as
``t' = t + rho`` and ``R' = Exp(phi) @ R``: ``rho`` moves the user origin in base [m], ``phi`` is
a rotation vector in base axes about the user origin [rad], applied on the left. The Gauss-Newton
Jacobian of a residual ``R p_user + t - p_base`` is then ``[I, -[R p_user]x]``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import apply, invert, make_transform

Array = NDArray[np.float64]
Estimator = Callable[[Array, Array], Array]

METHODS = ('three_point', 'five_point_lsq', 'rigid', 'robust')
DEFAULT_METHOD = 'rigid'
DUPLICATE_TOL = 1e-6      # [m] two points closer than this are the same point
MIN_COLLINEARITY = 1e-3   # s_min / s_max of the in-plane spread below this: collinear
PLANAR_TOL = 1e-6         # s3 / s1 of the user points below this: coplanar layout
ROBUST_THRESHOLD = 5e-4   # [m] default gross-error threshold of the robust method
ROBUST_K_SIGMA = 5.0      # robust method: also reject only beyond this many noise sigmas
MAX_COORDINATE = 1.0e3
"""[m] Coordinates beyond this are refused: no robot cell is a kilometre wide."""
LIMIT_FACTOR = 3.0
"""An achieved frame error above ``LIMIT_FACTOR`` times :func:`estimation_limit` is suspect:
for Gaussian noise it happens in well under 1 % of calibrations."""

_CHI3_MEDIAN = 1.5382     # median of the chi distribution with 3 dof
_FD_STEP = 1e-6           # [m] central-difference step of the covariance propagation
_COMPLETED = ('user points are coplanar: the column of M along their normal is unobservable, '
              'completed as the unit normal of the in-plane columns times their mean norm')
_TERMS = {
    0: ((0, 0),),
    1: ((0, 0), (1, 0), (0, 1)),
    2: ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)),
}


@dataclass(frozen=True, eq=False)
class FrameFit:
    """Result of a user-frame calibration; falsy on failure.

    ``condition_number`` is s_max / s_min of the singular values of the centred user points the
    fit used: over the two in-plane values for the rigid methods (a rigid pose needs only two
    directions), over all three for ``five_point_lsq`` on a non-coplanar layout (the affine M
    needs the third). ``collinearity`` is s2 / s1 of the same points, the smaller of the user and
    base sets (0 = collinear, 1 = isotropic in the plane). ``three_point`` reports both for its
    first three points, ``robust`` for its inliers.
    """

    method: str
    T_base_user: Array | None   # (4, 4) rigid pose of the user frame in base
    M: Array | None             # (4, 4) matrix used to map user -> base (affine for lsq)
    residuals: Array            # (N, 3) M p_user - p_base, all points incl. outliers [m]
    rms: float                  # RMS residual norm over inliers [m]
    max_residual: float         # largest residual norm over inliers [m]
    condition_number: float
    collinearity: float
    covariance: Array           # (6, 6) row-major (x y z rx ry rz) [m^2, m rad, rad^2]
    sigma: float                # point noise behind the covariance, estimated or given [m]
    scale: Array                # (3,) column norms of M's 3x3 (1 for rigid methods)
    shear: Array                # (3,) xy, xz, yz angles between M's columns - pi/2 [rad]
    outliers: tuple[int, ...]   # indices rejected by the robust method
    code: ErrorCode = ErrorCode.SUCCESS
    message: str = ''

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


@dataclass(frozen=True, eq=False)
class SurfaceModel:
    """Height correction in the user frame: dz(x, y) = sum_k c_k x^px_k y^py_k [m].

    ``coefficients[k]`` is in m^(1 - px - py). ``rms_before`` / ``rms_after`` are the RMS height
    residuals of the fitted points before and after the correction [m] (in-sample, so
    optimistic). Falsy when not valid.
    """

    powers_x: tuple[int, ...] = ()
    powers_y: tuple[int, ...] = ()
    coefficients: Array = field(default_factory=lambda: np.zeros(0))
    rms_before: float = math.inf
    rms_after: float = math.inf
    valid: bool = False
    message: str = ''

    def height(self, x: ArrayLike, y: ArrayLike) -> Array:
        """Correction dz [m] at user-frame x, y [m]; zero when not valid."""
        if not self.valid:
            return np.zeros(np.shape(x))
        terms = tuple(zip(self.powers_x, self.powers_y))
        V = _design(np.asarray(x, dtype=float), np.asarray(y, dtype=float), terms)
        return V @ self.coefficients

    def __bool__(self) -> bool:
        return self.valid


# ----------------------------------------------------------------------------- public API


def calibrate(method: str, p_user: ArrayLike, p_base: ArrayLike, **opts: float | None
              ) -> FrameFit:
    """Fit the user frame with ``method`` (one of ``METHODS``; '' = rigid). Arrays (N, 3) [m].

    ``opts`` go to the method's function (``sigma_prior`` for all, ``threshold`` and
    ``k_sigma`` for robust).
    """
    fitters: dict[str, Callable[..., FrameFit]] = {
        'three_point': fit_three_point, 'five_point_lsq': fit_five_point_lsq,
        'rigid': fit_rigid, 'robust': fit_robust}
    fitter = fitters.get(method or DEFAULT_METHOD)
    if fitter is None:
        return _failure(str(method), Failure(
            ErrorCode.UNKNOWN_METHOD,
            f'unknown method {method!r}; use one of: {", ".join(METHODS)}'))
    return fitter(p_user, p_base, **opts)


def fit_three_point(p_user: ArrayLike, p_base: ArrayLike, *, sigma_prior: float | None = None
                    ) -> FrameFit:
    """Paper eqs 3-5 on points 0, 1, 2: i along P1P2, k normal to P1P2 x P1P3, j = k x i.

    The same triad is built from the user points, so R = [i j k]_base [i j k]_user^T and
    t = P1_base - R P1_user (with P1_user at the origin and P2_user on the x axis this is the
    paper's M with O = P1). Residuals cover all N points; the covariance propagates the point
    noise through these formulas (it is larger than the rigid fit's), and the noise estimate
    divides by the effective dof of these non-least-squares residuals.
    """
    pu, pb, failure = _prepare(p_user, p_base, n_plane=3)
    if failure is not None:
        return _failure('three_point', failure)
    T = _three_point_pose(pu, pb)
    residuals = apply(T, pu) - pb
    J = _pose_jacobian(_three_point_pose, pu, pb)
    sigma, note = _noise_sigma(residuals, _effective_dof(J, pu, T[:3, :3]), sigma_prior)
    cov = _scaled(J @ J.T, sigma)
    return _assemble('three_point', T, T, residuals, (pu[:3], pb[:3]), cov, sigma, note)


def fit_five_point_lsq(p_user: ArrayLike, p_base: ArrayLike, *,
                       sigma_prior: float | None = None) -> FrameFit:
    """Paper eqs 6-8: least-squares affine M with B = M A, A rows [x y z 1] of the user points.

    On a coplanar user layout the column along the normal is completed (see module doc) and the
    message says so. ``T_base_user`` is the nearest rotation to M's 3x3 (SVD) with M's
    translation; residuals, scale and shear come from M itself.
    """
    pu, pb, failure = _prepare(p_user, p_base)
    if failure is not None:
        return _failure('five_point_lsq', failure)
    M, completed = _affine_fit(pu, pb)
    residuals = apply(M, pu) - pb
    sigma, note = _noise_sigma(residuals, residuals.size - (9 if completed else 12), sigma_prior)
    cov = _propagated_covariance(_affine_pose, pu, pb, sigma)
    s = _spread(pu)
    cond = s[0] / s[1] if completed else s[0] / s[2]
    nearly = '' if completed or cond < 1e3 else (
        f'user points are nearly coplanar (condition {cond:.3g}): the column of M along '
        'their normal is poorly determined')
    message = _join(_COMPLETED if completed else '', nearly, note)
    return _assemble('five_point_lsq', nearest_rigid(M), M, residuals, (pu, pb), cov, sigma,
                     message, condition=cond)


def fit_rigid(p_user: ArrayLike, p_base: ArrayLike, *, sigma_prior: float | None = None
              ) -> FrameFit:
    """Kabsch/Umeyama least-squares R, t (no scale, det R = +1): p_base ~ R p_user + t."""
    pu, pb, failure = _prepare(p_user, p_base)
    if failure is not None:
        return _failure('rigid', failure)
    return _rigid_fit('rigid', pu, pb, np.ones(len(pu), dtype=bool), sigma_prior)


def fit_robust(p_user: ArrayLike, p_base: ArrayLike, *, threshold: float = ROBUST_THRESHOLD,
               k_sigma: float = ROBUST_K_SIGMA, sigma_prior: float | None = None) -> FrameFit:
    """Rigid fit that rejects gross outliers (a marker touched wrong).

    A point is an outlier if it lies farther than ``max(threshold [m], k_sigma * sigma)`` from
    the fit of the others, sigma being their noise per coordinate (median based, or
    ``sigma_prior`` [m]). Each round drops the point with the largest leave-one-out residual
    while at least 4 points remain; then rejected points that fit the final inliers come back.
    If swapping a rejected point for an inlier also gives a consistent set (e.g. a corner's
    height error on the paper's 5-point layout), the outlier cannot be located: the result is
    DEGENERATE_POINTS naming both. Residuals cover all points; rms, max and the covariance
    only the inliers.
    """
    pu, pb, failure = _prepare(p_user, p_base)
    if failure is not None:
        return _failure('robust', failure)
    rule = _OutlierRule(threshold, k_sigma, sigma_prior)
    if len(pu) < 4:
        return _rigid_fit('robust', pu, pb, np.ones(len(pu), dtype=bool), sigma_prior,
                          message='only 3 points: at least 4 are needed to name an outlier; '
                          'plain rigid fit')
    keep = _reinstate(pu, pb, _drop_outliers(pu, pb, rule), rule)
    ambiguity = _ambiguity(pu, pb, keep, rule)
    if ambiguity is not None:
        return _failure('robust', ambiguity)
    residual, limit = rule.check(pu, pb, keep)
    notes = [f'rejected point {i}: {residual[i] * 1e3:.3f} mm off the fit of the inliers '
             f'(limit {limit * 1e3:.3f} mm); re-touch it' for i in np.flatnonzero(~keep)]
    outliers = tuple(int(i) for i in np.flatnonzero(~keep))
    return _rigid_fit('robust', pu, pb, keep, sigma_prior, outliers, _join(*notes))


def pose_covariance(p_user: ArrayLike, R: Array, sigma: float) -> Array:
    """(6, 6) covariance of a rigid least-squares fit's (t, phi) [m^2, m rad, rad^2].

    ``sigma^2 (J^T J)^-1`` with J rows ``[I, -[R p_user]x]`` (convention in the module doc) for
    isotropic point noise ``sigma`` [m] per coordinate. An infinite sigma gives inf on the
    diagonal (and zeros elsewhere), never NaN.
    """
    q = _as_points(p_user, 'p_user') @ R.T
    total = _skew(q.sum(axis=0))
    JtJ = np.zeros((6, 6))
    JtJ[:3, :3] = len(q) * np.eye(3)
    JtJ[:3, 3:] = -total
    JtJ[3:, :3] = total
    JtJ[3:, 3:] = (q * q).sum() * np.eye(3) - q.T @ q
    return _scaled(np.linalg.inv(JtJ), sigma)


def estimation_limit(p_user: ArrayLike, sigma: float, *, method: str = DEFAULT_METHOD,
                     n_trials: int | None = None, rng: np.random.Generator | None = None
                     ) -> tuple[float, float]:
    """Frame error expected from point noise alone: (translation [m], rotation [rad]) RMS.

    For isotropic noise ``sigma`` [m] per coordinate on the measured points, returns
    sqrt(trace) of the translation and rotation blocks of the pose covariance (the RMS of
    |t error| and |rotation error|), from the linearised covariance, or from ``n_trials``
    Monte-Carlo fits when given. It does not depend on the user frame's pose. Compare an
    achieved error with ``LIMIT_FACTOR`` times it. A degenerate layout gives (inf, inf).
    """
    pu = _as_points(p_user, 'p_user')
    estimate = _estimator(method)
    if _check_points(pu, pu, 3 if method == 'three_point' else None) is not None:
        return math.inf, math.inf
    if n_trials is not None:
        errors = _monte_carlo_errors(estimate, pu, sigma, n_trials, rng)
        return _rms(errors[:, :3]), _rms(errors[:, 3:])
    if method in ('rigid', 'robust'):
        cov = pose_covariance(pu, np.eye(3), sigma)
    else:
        cov = _propagated_covariance(estimate, pu, pu, sigma)
    return math.sqrt(np.trace(cov[:3, :3])), math.sqrt(np.trace(cov[3:, 3:]))


def fit_surface(p_user: ArrayLike, p_base: ArrayLike, M_base_user: Array,
                order: int | None = None) -> SurfaceModel:
    """Fit dz(x, y) = z_measured - z_nominal of the points in the user frame [m].

    The measured points are taken into the user frame with the inverse of ``M_base_user``,
    the map the calibration converts with (rigid, or the affine M of five_point_lsq); dz is
    fitted over the nominal x, y by least squares. ``order`` 0 (offset), 1 (1, x, y) or 2
    (adds x^2, xy, y^2); None picks the highest order that leaves at least one
    spare degree of freedom: 3 points -> 0, 4-6 points (the paper's 5) -> 1, 7+ -> 2. After a
    rigid fit the order-1 part is nearly zero (the fit took the tilt): the curvature terms need
    7 or more points.
    """
    pu, pb, failure = _prepare(p_user, p_base)
    if failure is not None:
        return SurfaceModel(message=failure.message)
    chosen = _surface_order(len(pu), order)
    if chosen is None:
        return SurfaceModel(message=f'{len(pu)} points cannot fit an order-{order} surface '
                            'with a spare degree of freedom; touch more markers or lower order')
    terms = _TERMS[chosen]
    dz = apply(np.linalg.inv(M_base_user), pb)[:, 2] - pu[:, 2]
    V = _design(pu[:, 0], pu[:, 1], terms)
    coefficients, _, rank, _ = np.linalg.lstsq(V, dz, rcond=None)
    if rank < len(terms):
        return SurfaceModel(message=f'the marker x, y layout cannot fit an order-{chosen} '
                            'surface; spread the markers over the plane')
    return SurfaceModel(tuple(p for p, _ in terms), tuple(p for _, p in terms), coefficients,
                        _rms(dz), _rms(dz - V @ coefficients), True,
                        f'order-{chosen} height correction from {len(pu)} points')


def user_to_base(T_base_user: Array, points: ArrayLike,
                 surface: SurfaceModel | None = None) -> Array:
    """Map user-frame points (N, 3) or (3,) [m] to base, first adding dz(x, y) along user z.

    ``T_base_user`` may be rigid or the affine ``FrameFit.M``."""
    p = np.array(points, dtype=float)
    if surface:
        p[..., 2] += surface.height(p[..., 0], p[..., 1])
    return apply(T_base_user, p)


def base_to_user(T_base_user: Array, points: ArrayLike,
                 surface: SurfaceModel | None = None) -> Array:
    """Inverse of :func:`user_to_base` for a rigid ``T_base_user``: base points [m] to user,
    then remove dz(x, y). (For an affine M, map with ``np.linalg.inv(M)`` instead.)"""
    p = apply(invert(T_base_user), points)
    if surface:
        p[..., 2] -= surface.height(p[..., 0], p[..., 1])
    return p


def collinearity(points: ArrayLike) -> float:
    """s2 / s1 of the centred points' singular values: 0 collinear .. 1 isotropic in-plane."""
    s = _spread(_as_points(points, 'points'))
    return float(s[1] / s[0]) if s[0] > 0.0 else 0.0


# ----------------------------------------------------------------------------- validation


def _as_points(points: ArrayLike, name: str) -> Array:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f'{name} must be an (N, 3) array [m], got shape {p.shape}')
    return p


def _prepare(p_user: ArrayLike, p_base: ArrayLike, n_plane: int | None = None
             ) -> tuple[Array, Array, Failure | None]:
    pu, pb = _as_points(p_user, 'p_user'), _as_points(p_base, 'p_base')
    return pu, pb, _check_points(pu, pb, n_plane)


def _check_points(pu: Array, pb: Array, n_plane: int | None) -> Failure | None:
    """The first data problem of a point-pair set, or None. ``n_plane``: points that span."""
    if len(pu) != len(pb):
        return Failure(ErrorCode.INVALID_INPUT, f'got {len(pu)} user points and {len(pb)} '
                       'base points; give one measured base point per nominal user point')
    if len(pu) < 3:
        return Failure(ErrorCode.TOO_FEW_POINTS, f'got {len(pu)} point(s); touch at least '
                       'three markers that are not on one line')
    for check in (_check_finite, _check_duplicates):
        for name, points in (('user', pu), ('base', pb)):
            failure = check(points, name)
            if failure is not None:
                return failure
    return _check_collinear(pu[:n_plane], pb[:n_plane], n_plane)


def _check_finite(points: Array, name: str) -> Failure | None:
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        return Failure(ErrorCode.INVALID_INPUT, f'{name} point {bad[0]} is not finite '
                       f'({points[bad[0]].tolist()}); re-measure it or leave it out')
    far = np.flatnonzero((np.abs(points) > MAX_COORDINATE).any(axis=1))
    if len(far):     # beyond any cell, and squares of ~1e154 m overflow inside the SVD
        return Failure(ErrorCode.INVALID_INPUT, f'{name} point {far[0]} is '
                       f'{points[far[0]].tolist()} m, beyond {MAX_COORDINATE:g} m from the '
                       'origin; points are in metres (not millimetres?)')
    return None


def _check_duplicates(points: Array, name: str) -> Failure | None:
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    i, j = np.nonzero(np.triu(d < DUPLICATE_TOL, k=1))
    if len(i) == 0:
        return None
    hint = ' (did the robot move between the two touches?)' if name == 'base' else ''
    return Failure(ErrorCode.DEGENERATE_POINTS, f'{name} points {i[0]} and {j[0]} coincide '
                   f'({d[i[0], j[0]] * 1e3:.4f} mm apart); each point must be a different '
                   f'marker{hint}')


def _check_collinear(pu: Array, pb: Array, n_plane: int | None) -> Failure | None:
    value = min(collinearity(pu), collinearity(pb))
    if value >= MIN_COLLINEARITY:
        return None
    which = f'the first {n_plane} points' if n_plane else 'the points'
    return Failure(ErrorCode.DEGENERATE_POINTS, f'{which} are (nearly) collinear (collinearity '
                   f'{value:.2e} < {MIN_COLLINEARITY:.0e}); touch at least three markers that '
                   'are not on one line')


# ----------------------------------------------------------------------------- estimators


def _kabsch(pu: Array, pb: Array) -> Array:
    """Least-squares rigid T_base_user (Kabsch), det R = +1 even for coplanar points."""
    cu, cb = pu.mean(axis=0), pb.mean(axis=0)
    U, _, Vt = np.linalg.svd((pu - cu).T @ (pb - cb))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return make_transform(R, cb - R @ cu)


def _triad(p: Array) -> Array:
    """Paper eqs 3-4 on p[0..2]: columns i = v12/|v12|, j = k x i, k = v12 x v13/|..|."""
    v12, v13 = p[1] - p[0], p[2] - p[0]
    k = np.cross(v12, v13)
    k /= np.linalg.norm(k)
    i = v12 / np.linalg.norm(v12)
    return np.column_stack([i, np.cross(k, i), k])


def _three_point_pose(pu: Array, pb: Array) -> Array:
    R = _triad(pb) @ _triad(pu).T
    return make_transform(R, pb[0] - R @ pu[0])


def _affine_fit(pu: Array, pb: Array) -> tuple[Array, bool]:
    """Paper eqs 6-8: (4, 4) M with p_base ~ M p_user; True if the normal column was completed."""
    _, s, Vt = np.linalg.svd(pu - pu.mean(axis=0))
    if s[2] > PLANAR_TOL * s[0]:
        A = np.column_stack([pu, np.ones(len(pu))])
        M = np.eye(4)
        M[:3, :] = np.linalg.lstsq(A, pb, rcond=None)[0].T
        return M, False
    return _planar_affine_fit(pu, pb, Vt[2]), True


def _planar_affine_fit(pu: Array, pb: Array, normal: Array) -> Array:
    """Fit M on in-plane coordinates, then complete M n from the in-plane columns.

    With a z = 0 layout the basis is (x, +-y, +-z), so M's z column becomes the unit normal of
    its x and y columns, scaled by their mean norm (right-handed).
    """
    E = _plane_basis(normal)
    c = pu.mean(axis=0)
    A = np.column_stack([(pu - c) @ E[:, :2], np.ones(len(pu))])
    g_a, g_b, g_0 = np.linalg.lstsq(A, pb, rcond=None)[0]
    normal_image = np.cross(g_a, g_b)
    mean_norm = 0.5 * (np.linalg.norm(g_a) + np.linalg.norm(g_b))
    normal_image *= mean_norm / np.linalg.norm(normal_image)
    M3 = np.column_stack([g_a, g_b, normal_image]) @ E.T
    return make_transform(M3, g_0 - M3 @ c)


def _plane_basis(normal: Array) -> Array:
    """Right-handed orthonormal columns (e1, e2, n), e1 the user x axis in the plane if it can."""
    n = normal / np.linalg.norm(normal)
    e1 = np.array([1.0, 0.0, 0.0]) - n[0] * n
    if np.linalg.norm(e1) < 0.5:
        e1 = np.array([0.0, 1.0, 0.0]) - n[1] * n
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(n, e1), n])


def nearest_rigid(M: Array) -> Array:
    """Polar decomposition: the rotation nearest M's 3x3 (det +1), with M's translation."""
    U, _, Vt = np.linalg.svd(M[:3, :3])
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return make_transform(R, M[:3, 3])


def _affine_pose(pu: Array, pb: Array) -> Array:
    return nearest_rigid(_affine_fit(pu, pb)[0])


def _estimator(method: str) -> Estimator:
    estimators: dict[str, Estimator] = {
        'three_point': _three_point_pose, 'five_point_lsq': _affine_pose,
        'rigid': _kabsch, 'robust': _kabsch}
    if method not in estimators:
        raise ValueError(f'unknown method {method!r}; use one of: {", ".join(METHODS)}')
    return estimators[method]


# ----------------------------------------------------------------------------- robust


@dataclass(frozen=True)
class _OutlierRule:
    threshold: float            # [m]
    k_sigma: float
    sigma_prior: float | None   # [m]

    def check(self, pu: Array, pb: Array, keep: Array) -> tuple[Array, float]:
        """Residual norms of all points under the fit of ``keep`` [m], and the limit [m]."""
        r = np.linalg.norm(apply(_kabsch(pu[keep], pb[keep]), pu) - pb, axis=1)
        sigma = _robust_sigma(r[keep]) if self.sigma_prior is None else self.sigma_prior
        return r, max(self.threshold, self.k_sigma * sigma)


def _drop_outliers(pu: Array, pb: Array, rule: _OutlierRule) -> Array:
    """Greedy: drop the worst point while it is beyond the limit; returns the inlier mask."""
    keep = np.ones(len(pu), dtype=bool)
    while keep.sum() >= 4:
        worst = _worst_point(pu, pb, keep, rule)
        if worst is None:
            break
        keep[worst] = False
    return keep


def _worst_point(pu: Array, pb: Array, keep: Array, rule: _OutlierRule) -> int | None:
    """The kept point farthest from the fit of the others, if farther than the limit."""
    worst, error, limit = None, 0.0, math.inf
    for i in np.flatnonzero(keep):
        rest = keep.copy()
        rest[i] = False
        if _check_collinear(pu[rest], pb[rest], None) is None:
            r, rest_limit = rule.check(pu, pb, rest)
            if r[i] > error:
                worst, error, limit = int(i), float(r[i]), rest_limit
    return worst if error > limit else None


def _reinstate(pu: Array, pb: Array, keep: Array, rule: _OutlierRule) -> Array:
    """Bring back rejected points within the limit of the final inliers' fit."""
    if keep.all():
        return keep
    r, limit = rule.check(pu, pb, keep)
    return keep | (r <= limit)


def _ambiguity(pu: Array, pb: Array, keep: Array, rule: _OutlierRule) -> Failure | None:
    """Failure if a rejected point swapped for an inlier also leaves a consistent set."""
    _, limit = rule.check(pu, pb, keep)
    for out in np.flatnonzero(~keep):
        rivals = []
        for inlier in np.flatnonzero(keep):
            trial = keep.copy()
            trial[[out, inlier]] = [True, False]
            if _consistent(pu, pb, trial, rule, limit):
                rivals.append(int(inlier))
        if rivals:
            named = ' or '.join(str(i) for i in [int(out), *rivals])
            return Failure(ErrorCode.DEGENERATE_POINTS, f'a gross error is present, but the '
                           f'layout cannot tell which of points {named} is wrong (dropping '
                           'either leaves a consistent fit); re-touch them, or lay out the '
                           'markers with no three on a line')
    return None


def _consistent(pu: Array, pb: Array, trial: Array, rule: _OutlierRule, limit: float) -> bool:
    """True if no point of ``trial`` would be rejected: each within ``limit`` [m] of the fit
    of the others (where those span a plane) and of the fit of all."""
    if _check_collinear(pu[trial], pb[trial], None) is not None:
        return False
    r, _ = rule.check(pu, pb, trial)
    if r[trial].max() > limit:
        return False
    for m in np.flatnonzero(trial):
        rest = trial.copy()
        rest[m] = False
        spans = _check_collinear(pu[rest], pb[rest], None) is None
        if spans and rule.check(pu, pb, rest)[0][m] > limit:
            return False
    return True


def _robust_sigma(norms: Array) -> float:
    """Per-coordinate noise [m] from the median residual norm of a rigid fit of n points."""
    n = len(norms)
    return float(np.median(norms)) / _CHI3_MEDIAN * math.sqrt(n / max(n - 2, 1))


# ----------------------------------------------------------------------------- results


def _rigid_fit(method: str, pu: Array, pb: Array, keep: Array, sigma_prior: float | None,
               outliers: tuple[int, ...] = (), message: str = '') -> FrameFit:
    T = _kabsch(pu[keep], pb[keep])
    residuals = apply(T, pu) - pb
    sigma, note = _noise_sigma(residuals[keep], 3 * keep.sum() - 6, sigma_prior)
    cov = pose_covariance(pu[keep], T[:3, :3], sigma)
    return _assemble(method, T, T, residuals, (pu[keep], pb[keep]), cov, sigma,
                     _join(message, note), outliers=outliers, keep=keep)


def _assemble(method: str, T: Array, M: Array, residuals: Array, used: tuple[Array, Array],
              cov: Array, sigma: float, message: str, *, condition: float | None = None,
              outliers: tuple[int, ...] = (), keep: Array | None = None) -> FrameFit:
    norms = np.linalg.norm(residuals if keep is None else residuals[keep], axis=1)
    s = _spread(used[0])
    scale, shear = _scale_shear(M[:3, :3])
    return FrameFit(
        method=method, T_base_user=T, M=M, residuals=residuals, rms=_rms(norms),
        max_residual=float(norms.max()),
        condition_number=float(s[0] / s[1]) if condition is None else float(condition),
        collinearity=min(collinearity(used[0]), collinearity(used[1])), covariance=cov,
        sigma=sigma, scale=scale, shear=shear, outliers=outliers, message=message)


def _failure(method: str, failure: Failure) -> FrameFit:
    return FrameFit(
        method=method, T_base_user=None, M=None, residuals=np.zeros((0, 3)), rms=math.inf,
        max_residual=math.inf, condition_number=math.inf, collinearity=0.0,
        covariance=_scaled(np.eye(6), math.inf), sigma=math.inf, scale=np.ones(3),
        shear=np.zeros(3), outliers=(), code=failure.code, message=failure.message)


def _scale_shear(M3: Array) -> tuple[Array, Array]:
    """Column norms of M3 and the xy, xz, yz angles between its columns minus pi/2 [rad]."""
    gram = M3.T @ M3
    shear = [math.atan2(math.sqrt(max(0.0, gram[a, a] * gram[b, b] - gram[a, b] ** 2)),
                        gram[a, b]) - math.pi / 2 for a, b in ((0, 1), (0, 2), (1, 2))]
    return np.sqrt(np.diag(gram)), np.array(shear)


def _noise_sigma(residuals: Array, dof: float, sigma_prior: float | None
                 ) -> tuple[float, str]:
    """Point noise per coordinate [m]: the prior, or sqrt(sum |r|^2 / dof); inf without dof."""
    if sigma_prior is not None:
        return float(sigma_prior), ''
    if dof <= 1e-9:
        return math.inf, ('no spare measurements to estimate the noise: covariance is inf; '
                          'give sigma_prior or touch more markers')
    return math.sqrt(float((residuals ** 2).sum()) / dof), ''


def _propagated_covariance(estimate: Estimator, pu: Array, pb: Array, sigma: float) -> Array:
    """sigma^2 J J^T: isotropic noise on p_base propagated through ``estimate`` (linearised)."""
    if not math.isfinite(sigma):
        return _scaled(np.eye(6), math.inf)
    J = _pose_jacobian(estimate, pu, pb)
    return _scaled(J @ J.T, sigma)


def _pose_jacobian(estimate: Estimator, pu: Array, pb: Array) -> Array:
    """(6, 3N) d(rho, phi) / d p_base (row-major points) by central differences."""
    T0 = estimate(pu, pb)
    flat = pb.ravel()
    J = np.empty((6, flat.size))
    for k in range(flat.size):
        step = np.zeros_like(flat)
        step[k] = _FD_STEP
        plus = _pose_delta(estimate(pu, (flat + step).reshape(-1, 3)), T0)
        minus = _pose_delta(estimate(pu, (flat - step).reshape(-1, 3)), T0)
        J[:, k] = (plus - minus) / (2.0 * _FD_STEP)
    return J


def _effective_dof(J: Array, pu: Array, R: Array) -> float:
    """E[sum |r|^2] / sigma^2 for a rigid estimator with pose Jacobian J: ||A J - I||_F^2.

    A stacks the rows [I, -[R p]x] (residual w.r.t. pose); for least squares this is 3N - 6.
    """
    A = np.concatenate([np.hstack([np.eye(3), -_skew(q)]) for q in pu @ R.T])
    return float(np.sum((A @ J - np.eye(len(A))) ** 2))


def _pose_delta(T: Array, T0: Array) -> Array:
    """(rho, phi) with T = (t0 + rho, Exp(phi) R0) [m, rad]."""
    phi = Rotation.from_matrix(T[:3, :3] @ T0[:3, :3].T).as_rotvec()
    return np.concatenate([T[:3, 3] - T0[:3, 3], phi])


def _monte_carlo_errors(estimate: Estimator, pu: Array, sigma: float, n_trials: int,
                        rng: np.random.Generator | None) -> Array:
    """(n_trials, 6) pose errors of fits to p_user plus N(0, sigma^2) noise [m, rad]."""
    rng = np.random.default_rng(0) if rng is None else rng
    return np.array([_pose_delta(estimate(pu, pu + rng.normal(0.0, sigma, pu.shape)),
                                 np.eye(4)) for _ in range(n_trials)])


def _scaled(cov_unit: Array, sigma: float) -> Array:
    if math.isfinite(sigma):
        return sigma ** 2 * cov_unit
    return np.diag(np.full(6, math.inf))


# ----------------------------------------------------------------------------- helpers


def _surface_order(n_points: int, order: int | None) -> int | None:
    if order is None:
        return max(o for o, terms in _TERMS.items() if len(terms) < n_points)
    if order not in _TERMS:
        raise ValueError(f'surface order must be one of {sorted(_TERMS)}, got {order!r}')
    return order if len(_TERMS[order]) < n_points else None


def _design(x: Array, y: Array, terms: tuple[tuple[int, int], ...]) -> Array:
    return np.stack([x ** px * y ** py for px, py in terms], axis=-1)


def _spread(points: Array) -> Array:
    return np.linalg.svd(points - points.mean(axis=0), compute_uv=False)


def _skew(v: Array) -> Array:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rms(values: Array) -> float:
    """RMS of vector norms (rows of a 2-D array) or of scalars [same unit]."""
    v = np.asarray(values, dtype=float)
    squares = (v ** 2).sum(axis=1) if v.ndim == 2 else v ** 2
    return float(math.sqrt(squares.mean()))


def _join(*parts: str) -> str:
    return '; '.join(p for p in parts if p)
