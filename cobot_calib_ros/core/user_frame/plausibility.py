"""Sanity gate of a fit: residuals and scale that no touched user frame can have.

A rigid fit of base points in millimetres to user points in metres "succeeds" with an RMS
residual of ~100 m; the affine fit of the same points succeeds with tiny residuals and a scale
of 1000. :func:`check_plausible` turns such fits into an IMPLAUSIBLE_FIT failure that says what
is wrong and what to do; calibrate() applies it with generous defaults.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.user_frame.checks import point_names
from cobot_calib_ros.core.user_frame.result import FrameFit

MAX_RMS_ERROR = 0.01
"""[m] calibrate()'s default RMS limit: 10 mm, far beyond any touch error, within any unit mix."""
MAX_SCALE_ERROR = 0.01
"""calibrate()'s default limit of |scale - 1| of the affine M (1 %: 2 mm over 0.2 m)."""
MAX_RESIDUAL_FACTOR = 3.0
"""Default largest-residual limit of :func:`check_plausible`, times ``max_rms_error``."""
_UNITS_SCALE = 0.1        # |scale - 1| beyond this (10 %) is no robot error: units, or layout
_UNITS_RMS = 0.1          # [m] an RMS residual beyond this is no touch error: units, or order
_UNITS = 'are base points in millimetres and user points in metres (or the reverse)?'


def check_plausible(fit: FrameFit, max_rms_error: float,
                    max_scale_error: float = MAX_SCALE_ERROR, *,
                    max_residual_error: float | None = None,
                    names: Sequence[str] | None = None) -> Failure | None:
    """None if ``fit`` is a plausible calibration, else a Failure saying what to do.

    Checks, in order: the affine scale (column norms of M) within ``max_scale_error`` of 1, the
    RMS residual within ``max_rms_error`` [m], and the largest inlier residual within
    ``max_residual_error`` [m] (default ``MAX_RESIDUAL_FACTOR * max_rms_error``); codes are
    IMPLAUSIBLE_FIT. A failed fit gives its own failure back. ``names`` (default P1..Pn) name
    the points.
    """
    if not fit:
        return Failure(fit.code, fit.message)
    if max_residual_error is None:
        max_residual_error = MAX_RESIDUAL_FACTOR * max_rms_error
    if not min(max_rms_error, max_scale_error, max_residual_error) > 0.0:
        raise ValueError(f'limits must be > 0, got max_rms_error={max_rms_error!r}, '
                         f'max_scale_error={max_scale_error!r}, '
                         f'max_residual_error={max_residual_error!r}')
    for problem in (_check_scale(fit, max_scale_error), _check_rms(fit, max_rms_error),
                    _check_largest(fit, max_residual_error, names)):
        if problem is not None:     # (a Failure is falsy: no `or` chain)
            return problem
    return None


def _check_scale(fit: FrameFit, max_scale_error: float) -> Failure | None:
    worst = int(np.argmax(np.abs(fit.scale - 1.0)))
    scale = float(fit.scale[worst])
    if abs(scale - 1.0) <= max_scale_error:
        return None
    if abs(scale - 1.0) <= _UNITS_SCALE:
        hint = ('the measured layout is not the nominal one: check the user coordinates of the '
                'points, re-touch them, or use the rigid method')
    elif scale > 1.0:
        hint = (f'the base points are {scale:.4g} times the size of the user points: are base '
                'points in millimetres and user points in metres? Give both in metres')
    else:
        hint = (f'the user points are {1.0 / scale:.4g} times the size of the base points: are '
                'user points in millimetres and base points in metres? Give both in metres')
    return Failure(ErrorCode.IMPLAUSIBLE_FIT, (
        f'scale {scale:.6g} of M (axis {"xyz"[worst]}) is off 1 by {abs(scale - 1.0):.3g} > '
        f'max_scale_error {max_scale_error:.3g}: {hint}'))


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
