"""Sanity gate of a fit: residuals and scale that no touched user frame can have.

A rigid fit of base points in millimetres to user points in metres "succeeds" with an RMS
residual of ~100 m; the affine fit of the same points succeeds with tiny residuals and a scale
of 1000. :func:`check_plausible` turns such fits into an IMPLAUSIBLE_FIT failure that says what
is wrong and what to do; calibrate() applies it with generous defaults.

The scale is judged by its own uncertainty: a column norm of M is refused only when it is off 1
by more than ``max_scale_error`` AND by more than k of its standard errors (``FrameFit.scale_se``,
the point noise propagated through the affine fit). k is the two-sided Student-t quantile (normal
with ``sigma_prior``) at ``SCALE_FALSE_REFUSAL`` split over the three axes (Bonferroni), so clean
data is refused in at most that fraction of calibrations whatever the layout; a thin layout
(6 points over 8 cm, 0.1 mm noise: scale 1.016 +- 0.005) is no longer refused for its noise.
Without spare points (no residual degrees of freedom) the tolerance alone decides.
"""
from __future__ import annotations

from typing import Sequence

import math

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.user_frame.checks import point_names
from cobot_calib_ros.core.user_frame.result import FrameFit

MAX_RMS_ERROR = 0.01
"""[m] calibrate()'s default RMS limit: 10 mm, far beyond any touch error, within any unit mix."""
MAX_SCALE_ERROR = 0.01
"""calibrate()'s default tolerance of |scale - 1| of the affine M (1 %: 2 mm over 0.2 m)."""
SCALE_FALSE_REFUSAL = 0.005
"""Target fraction of clean calibrations whose scale the gate refuses (noise alone)."""
MAX_RESIDUAL_FACTOR = 3.0
"""Default largest-residual limit of :func:`check_plausible`, times ``max_rms_error``."""
_UNITS_SCALE = 0.1        # |scale - 1| beyond this (10 %) is no robot error: units, or layout
_UNITS_RMS = 0.1          # [m] an RMS residual beyond this is no touch error: units, or order
_UNITS = 'are base points in millimetres and user points in metres (or the reverse)?'


def check_plausible(fit: FrameFit, max_rms_error: float,
                    max_scale_error: float = MAX_SCALE_ERROR, *,
                    max_residual_error: float | None = None,
                    names: Sequence[str] | None = None,
                    scale_false_refusal: float = SCALE_FALSE_REFUSAL) -> Failure | None:
    """None if ``fit`` is a plausible calibration, else a Failure saying what to do.

    Checks, in order: M keeps handedness (det > 0), the affine scale (column norms of M)
    within ``max_scale_error`` of 1 or within its noise (k standard errors for a
    ``scale_false_refusal`` rate; module doc), the RMS residual within ``max_rms_error`` [m],
    and the largest inlier residual within ``max_residual_error`` [m] (default
    ``MAX_RESIDUAL_FACTOR * max_rms_error``); codes are IMPLAUSIBLE_FIT. A failed fit gives its
    own failure back. ``names`` (default P1..Pn) name the points.
    """
    if not fit:
        return Failure(fit.code, fit.message)
    if max_residual_error is None:
        max_residual_error = MAX_RESIDUAL_FACTOR * max_rms_error
    if not min(max_rms_error, max_scale_error, max_residual_error) > 0.0:
        raise ValueError(f'limits must be > 0, got max_rms_error={max_rms_error!r}, '
                         f'max_scale_error={max_scale_error!r}, '
                         f'max_residual_error={max_residual_error!r}')
    if not 0.0 < scale_false_refusal < 1.0:
        raise ValueError(f'need 0 < scale_false_refusal < 1, got {scale_false_refusal!r}')
    for problem in (_check_handedness(fit),
                    _check_scale(fit, max_scale_error, scale_false_refusal),
                    _check_rms(fit, max_rms_error),
                    _check_largest(fit, max_residual_error, names)):
        if problem is not None:     # (a Failure is falsy: no `or` chain)
            return problem
    return None


def _check_handedness(fit: FrameFit) -> Failure | None:
    """A mirror (det M < 0) fits a non-coplanar layout whose user coordinates are mirrored."""
    if fit.M is None or np.linalg.det(fit.M[:3, :3]) > 0.0:
        return None
    return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
        'M mirrors the layout (det < 0): the user points are a mirror image of the measured '
        'ones; check the sign of each user axis (a left-handed drawing?) and the point order'))


def _check_scale(fit: FrameFit, max_scale_error: float, false_refusal: float
                 ) -> Failure | None:
    off = np.abs(fit.scale - 1.0)
    k = scale_significance(fit.noise_dof, false_refusal)
    with np.errstate(invalid='ignore'):
        noise = k * fit.scale_se        # inf or nan: uncertainty unknown, the tolerance decides
    noise = np.where(np.isfinite(noise), noise, 0.0)
    refused = off > np.maximum(max_scale_error, noise)
    if not refused.any():
        return None
    worst = int(np.argmax(np.where(refused, off, -1.0)))      # the farthest refused axis
    scale = float(fit.scale[worst])
    if abs(scale - 1.0) <= _UNITS_SCALE:
        hint = ('the measured layout is not the nominal one: check the user coordinates of the '
                'points, re-touch them, or use the rigid method')
    elif scale > 1.0:
        hint = (f'the base points are {scale:.4g} times the size of the user points: are base '
                'points in millimetres and user points in metres? Give both in metres')
    else:
        hint = (f'the user points are {1.0 / scale:.4g} times the size of the base points: are '
                'user points in millimetres and base points in metres? Give both in metres')
    se = float(fit.scale_se[worst])
    judged = (f' and > {k:.3g} standard errors of {se:.2g}' if math.isfinite(se) else
              ' (no spare points to tell its uncertainty: touch more markers)')
    return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
        f'scale {scale:.6g} of M (axis {"xyz"[worst]}) is off 1 by {off[worst]:.3g} > '
        f'max_scale_error {max_scale_error:.3g}{judged}: {hint}'))


def scale_significance(noise_dof: float, false_refusal: float = SCALE_FALSE_REFUSAL) -> float:
    """k: |scale - 1| beyond k standard errors happens on clean data at ``false_refusal``.

    Two-sided, split over the three axes; Student t with ``noise_dof`` degrees of freedom (normal
    when infinite, i.e. a sigma_prior); inf without degrees of freedom.
    """
    from scipy.stats import norm, t     # here: importing scipy.stats takes 0.35 s
    level = false_refusal / 6.0
    if math.isinf(noise_dof):
        return float(norm.isf(level))
    return float(t.isf(level, noise_dof)) if noise_dof > 0.0 else math.inf


def _check_rms(fit: FrameFit, max_rms_error: float) -> Failure | None:
    if fit.rms <= max_rms_error:
        return None
    if fit.rms > _UNITS_RMS:
        hint = (f'{_UNITS} Give both in metres, and check that each base point is the same '
                'marker as its user point')
    else:
        hint = ('check that each base point is the same marker as its user point (same order), '
                'and re-touch the points')
    return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
        f'RMS residual {_length(fit.rms)} > max_rms_error {_length(max_rms_error)}: {hint}'))


def _check_largest(fit: FrameFit, max_residual_error: float, names: Sequence[str] | None
                   ) -> Failure | None:
    if fit.max_residual <= max_residual_error:
        return None
    norms = np.linalg.norm(fit.residuals, axis=1)
    norms[list(fit.outliers)] = -1.0
    name = point_names(len(norms), names)[int(np.argmax(norms))]
    return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
        f'largest residual {_length(fit.max_residual)} at {name} > max_residual_error '
        f'{_length(max_residual_error)}: re-touch {name} (or calibrate with the robust method, '
        'which rejects such a point)'))


def _length(value: float) -> str:
    """A length [m] for a message, in metres, and in millimetres too when below 1 m."""
    return f'{value:.4g} m' if value >= 1.0 else f'{value:.4g} m ({value * 1e3:.4g} mm)'
