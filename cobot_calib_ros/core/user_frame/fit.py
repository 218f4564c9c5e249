"""User-frame calibration from touched points: the methods and calibrate(); SI units (m, rad).

Inputs are ``p_user`` (N, 3), nominal marker positions in the user frame [m], and ``p_base``
(N, 3), the same markers measured in the robot base frame [m]. Every method returns a
:class:`FrameFit` that is falsy on failure (data problems are values; wrong shapes raise).
Messages name the points ``names`` (default P1..Pn).

Methods (``METHODS``):

- ``three_point``: the paper's eqs 3-5 (section 2.1) on the first three points only.
- ``five_point_lsq``: the paper's eqs 6-8 (section 2.2): the 12-parameter affine ``M`` by least
  squares. On a coplanar user layout (all z = 0, as in the paper) ``A`` has rank 3 and ``M``'s
  column along the plane normal is unobservable; it is completed from the two in-plane columns.
- ``rigid`` (default): Kabsch/Umeyama SVD fit without scale, reflection guarded.
- ``robust``: the rigid fit with a studentized leave-one-out test of gross outliers (robust.py).

The pose covariance convention is in covariance.py; calibrate() refuses implausible fits
(plausibility.py).
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import apply
from cobot_calib_ros.core.user_frame.jacobians import (
    affine_jacobian, nearest_rigid_jacobian, three_point_jacobian)
from cobot_calib_ros.core.user_frame.checks import _prepare
from cobot_calib_ros.core.user_frame.covariance import (
    _effective_dof, _noise_sigma, _scale_standard_errors, _scaled)
from cobot_calib_ros.core.user_frame.estimators import (
    _affine_fit, _three_point_pose, DEFAULT_METHOD, METHODS, nearest_rigid)
from cobot_calib_ros.core.user_frame.geometry import _join, _spread
from cobot_calib_ros.core.user_frame.plausibility import (
    check_plausible, MAX_RMS_ERROR, MAX_SCALE_ERROR)
from cobot_calib_ros.core.user_frame.result import (
    _assemble, _failure, _noise_dof, _rigid_fit, FrameFit)
from cobot_calib_ros.core.user_frame.robust import fit_robust

_COMPLETED = ('user points are coplanar: the column of M along their normal is unobservable, '
              'completed as the unit normal of the in-plane columns times their mean norm')


def calibrate(method: str, p_user: ArrayLike, p_base: ArrayLike, *,
              names: Sequence[str] | None = None, max_rms_error: float | None = MAX_RMS_ERROR,
              max_scale_error: float = MAX_SCALE_ERROR, **opts: float | None) -> FrameFit:
    """Fit the user frame with ``method`` (one of ``METHODS``; '' = rigid). Arrays (N, 3) [m].

    ``names`` (default P1..Pn) name the points in messages. A fit that
    :func:`check_plausible` refuses with ``max_rms_error`` [m] and ``max_scale_error`` comes
    back falsy with IMPLAUSIBLE_FIT (``max_rms_error=None``: no check). ``opts`` go to the
    method's function (``sigma_prior`` for all, ``threshold`` and ``false_rejection`` for
    robust).
    """
    fitters: dict[str, Callable[..., FrameFit]] = {
        'three_point': fit_three_point, 'five_point_lsq': fit_five_point_lsq,
        'rigid': fit_rigid, 'robust': fit_robust}
    fitter = fitters.get(method or DEFAULT_METHOD)
    if fitter is None:
        return _failure(str(method), Failure(
            ErrorCode.UNKNOWN_METHOD,
            f'unknown method {method!r}; use one of: {", ".join(METHODS)}'))
    fit = fitter(p_user, p_base, names=names, **opts)
    if not fit or max_rms_error is None:
        return fit
    problem = check_plausible(fit, max_rms_error, max_scale_error, names=names)
    return fit if problem is None else _failure(fit.method, problem)


def fit_three_point(p_user: ArrayLike, p_base: ArrayLike, *, sigma_prior: float | None = None,
                    names: Sequence[str] | None = None) -> FrameFit:
    """Paper eqs 3-5 on points 0, 1, 2: i along P1P2, k normal to P1P2 x P1P3, j = k x i.

    The same triad is built from the user points, so R = [i j k]_base [i j k]_user^T and
    t = P1_base - R P1_user (with P1_user at the origin and P2_user on the x axis this is the
    paper's M with O = P1). Residuals cover all N points; the covariance propagates the point
    noise through these formulas (it is larger than the rigid fit's), and the noise estimate
    divides by the effective dof of these non-least-squares residuals.
    """
    pu, pb, _, failure = _prepare(p_user, p_base, names, n_plane=3)
    if failure is not None:
        return _failure('three_point', failure)
    T = _three_point_pose(pu, pb)
    residuals = apply(T, pu) - pb
    J = three_point_jacobian(pu, pb)
    dof = _effective_dof(J, pu, T[:3, :3])
    sigma, note = _noise_sigma(residuals, dof, sigma_prior)
    cov = _scaled(J @ J.T, sigma)
    return _assemble('three_point', T, T, residuals, (pu[:3], pb[:3]), cov, sigma, note,
                     noise_dof=_noise_dof(dof, sigma_prior))


def fit_five_point_lsq(p_user: ArrayLike, p_base: ArrayLike, *,
                       sigma_prior: float | None = None, names: Sequence[str] | None = None
                       ) -> FrameFit:
    """Paper eqs 6-8: least-squares affine M with B = M A, A rows [x y z 1] of the user points.

    On a coplanar user layout the column along the normal is completed (see module doc) and the
    message says so. ``T_base_user`` is the nearest rotation to M's 3x3 (SVD) with M's
    translation; residuals, scale and shear come from M itself, and ``scale_se`` propagates the
    noise estimate (or ``sigma_prior``) to the scale, which the plausibility gate judges it by.
    """
    pu, pb, _, failure = _prepare(p_user, p_base, names)
    if failure is not None:
        return _failure('five_point_lsq', failure)
    M, completed = _affine_fit(pu, pb)
    residuals = apply(M, pu) - pb
    dof = residuals.size - (9 if completed else 12)
    sigma, note = _noise_sigma(residuals, dof, sigma_prior)
    dM = affine_jacobian(pu, pb)
    J = nearest_rigid_jacobian(M, dM)
    cov = _scaled(J @ J.T, sigma)
    s = _spread(pu)
    cond = s[0] / s[1] if completed else s[0] / s[2]
    nearly = '' if completed or cond < 1e3 else (
        f'user points are nearly coplanar (condition {cond:.3g}): the column of M along '
        'their normal is poorly determined')
    message = _join(_COMPLETED if completed else '', nearly, note)
    return _assemble('five_point_lsq', nearest_rigid(M), M, residuals, (pu, pb), cov, sigma,
                     message, condition=cond, scale_se=_scale_standard_errors(M, dM, sigma),
                     noise_dof=_noise_dof(dof, sigma_prior))


def fit_rigid(p_user: ArrayLike, p_base: ArrayLike, *, sigma_prior: float | None = None,
              names: Sequence[str] | None = None) -> FrameFit:
    """Kabsch/Umeyama least-squares R, t (no scale, det R = +1): p_base ~ R p_user + t."""
    pu, pb, _, failure = _prepare(p_user, p_base, names)
    if failure is not None:
        return _failure('rigid', failure)
    return _rigid_fit('rigid', pu, pb, np.ones(len(pu), dtype=bool), sigma_prior)
