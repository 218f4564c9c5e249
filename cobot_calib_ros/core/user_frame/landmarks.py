"""User frame from fiducials seen by the wrist camera (issue 11); pure, SI units (m, rad).

- ``landmark_single`` (:func:`frame_from_single`): the first paper's built-in landmark method
  (Intera RPS): one marker seen from one viewpoint gives the whole frame,
  ``T_base_user = T_base_marker @ inv(T_user_marker)``.
- ``landmark_multi`` (:func:`frame_from_landmarks`): several markers, several views each. Each
  marker's centre is averaged over its views (weighted by the inverse of its position
  covariance), then the nominal centres (user frame) are fitted to the measured ones (base) with
  the ``rigid`` method of :func:`cobot_calib_ros.core.user_frame.calibrate`. The markers'
  orientations only break the tie when fewer than three markers were seen: then points along
  each marker's x and y axes (``AXIS_POINT`` from its centre) join the fit.

Both return a :class:`FrameFit` whose ``method`` is the landmark method's name, and the point
names and point pairs the fit used (what a user-frame record stores). Covariances are in the
convention of covariance.py: (x y z rx ry rz), ``t' = t + rho``, ``R' = Exp(phi) R``, base axes.
"""
from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.frames import apply, invert, Rotation
from cobot_calib_ros.core.user_frame.estimators import METHODS
from cobot_calib_ros.core.user_frame.fit import calibrate
from cobot_calib_ros.core.frames import skew
from cobot_calib_ros.core.user_frame.geometry import Array
from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR
from cobot_calib_ros.core.user_frame.result import _assemble, _failure, FrameFit

LANDMARK_SINGLE = 'landmark_single'
LANDMARK_MULTI = 'landmark_multi'
LANDMARK_METHODS = (LANDMARK_SINGLE, LANDMARK_MULTI)
CALIBRATION_METHODS = (*METHODS, *LANDMARK_METHODS)
"""Every method of a user-frame calibration: from touched points, then from the wrist camera."""


def method_problem(method: str) -> Failure | None:
    """None for one of CALIBRATION_METHODS or '' (the default, rigid), else UNKNOWN_METHOD
    naming them: checked before anything else of a request, so that a bad method is named as
    such and not as the data missing for it."""
    if not method or method in CALIBRATION_METHODS:
        return None
    return Failure(ErrorCode.UNKNOWN_METHOD, f'unknown method {method!r}; one of: '
                   f'{", ".join(CALIBRATION_METHODS)}')
AXIS_POINT = 0.05          # [m] axis points' distance from a marker's centre (tie-breaker)
MIN_POSITION_VARIANCE = 1e-12   # [m^2] floor of a view's position covariance eigenvalues

Observation = tuple[int, ArrayLike, ArrayLike]   # (marker id, T_base_marker, 6x6 covariance)


@dataclasses.dataclass(frozen=True)
class LandmarkFit:
    """A landmark method's result: the fit and the point pairs behind it; falsy on failure,
    with the failure's ``code`` and ``message`` (those of the fit)."""

    fit: FrameFit
    names: list[str]        # one per point pair: 'L<id>', and 'L<id>+x' / 'L<id>+y'
    p_user: Array           # (N, 3) nominal points, user frame [m]
    p_base: Array           # (N, 3) measured points, base frame [m]
    views: dict[int, int]   # marker id -> views averaged

    def __bool__(self) -> bool:
        return bool(self.fit)

    @property
    def code(self) -> ErrorCode:
        return self.fit.code

    @property
    def message(self) -> str:
        return self.fit.message

    @classmethod
    def failed(cls, method: str, failure: Failure) -> 'LandmarkFit':
        """A falsy result of ``method`` carrying ``failure``, with no point pairs."""
        return cls(_failure(method, failure), [], np.zeros((0, 3)), np.zeros((0, 3)), {})


def _axis_points(T: Array) -> Array:
    """(3, 3) a marker frame's centre and the points AXIS_POINT along its x and y axes."""
    return apply(T, np.array([[0.0, 0.0, 0.0], [AXIS_POINT, 0.0, 0.0], [0.0, AXIS_POINT, 0.0]]))


def _names(marker_id: int) -> list[str]:
    return [f'L{marker_id}', f'L{marker_id}+x', f'L{marker_id}+y']


def frame_from_single(T_base_marker: ArrayLike, T_user_marker: ArrayLike, *,
                      covariance: ArrayLike | None = None, marker_id: int = 0) -> LandmarkFit:
    """The user frame from one marker pose: ``T_base_marker @ inv(T_user_marker)``.

    ``covariance`` (6, 6) of T_base_marker in base axes (module convention, about the marker
    centre) is carried to the user origin; without it the covariance is NaN. Residuals (zero up
    to rounding) are given for the marker's centre and axis points.
    """
    Tbm, Tum = np.asarray(T_base_marker, dtype=float), np.asarray(T_user_marker, dtype=float)
    if Tbm.shape != (4, 4) or Tum.shape != (4, 4):
        raise ValueError('T_base_marker and T_user_marker must be (4, 4)')
    if not (np.all(np.isfinite(Tbm)) and np.all(np.isfinite(Tum))):
        return LandmarkFit.failed(LANDMARK_SINGLE, Failure(
            ErrorCode.INVALID_INPUT, f'marker {marker_id}: pose contains NaN or inf'))
    T = Tbm @ invert(Tum)
    pu, pb = _axis_points(Tum), _axis_points(Tbm)
    if covariance is None:
        cov = np.full((6, 6), np.nan)
    else:
        # rho_user = rho_marker + phi x (t_user - t_marker); phi unchanged
        J = np.eye(6)
        J[:3, 3:] = -skew(T[:3, 3] - Tbm[:3, 3])
        cov = J @ np.asarray(covariance, dtype=float) @ J.T
    fit = _assemble(LANDMARK_SINGLE, T, T, apply(T, pu) - pb, (pu, pb), cov, float('nan'),
                    f'one view of marker {marker_id}')
    return LandmarkFit(fit, _names(marker_id), pu, pb, {marker_id: 1})


def average_centre(positions: ArrayLike, covariances: ArrayLike) -> tuple[Array, Array]:
    """Inverse-covariance weighted mean of (K, 3) positions with (K, 3, 3) covariances [m^2];
    the mean and its covariance."""
    P = np.asarray(positions, dtype=float).reshape(-1, 3)
    info, vec = np.zeros((3, 3)), np.zeros(3)
    for p, C in zip(P, np.asarray(covariances, dtype=float).reshape(-1, 3, 3)):
        w, V = np.linalg.eigh(0.5 * (C + C.T))
        W = V @ np.diag(1.0 / np.maximum(w, MIN_POSITION_VARIANCE)) @ V.T
        info += W
        vec += W @ p
    cov = np.linalg.inv(info)
    return cov @ vec, cov


def _mean_rotation(Rs: Sequence[Array]) -> Array:
    return Rotation.from_matrix(np.asarray(Rs)).mean().as_matrix()


def frame_from_landmarks(observations: Sequence[Observation],
                         T_user_marker: Mapping[int, ArrayLike], *,
                         max_rms_error: float | None = MAX_RMS_ERROR,
                         max_scale_error: float = MAX_SCALE_ERROR,
                         sigma_prior: float | None = None) -> LandmarkFit:
    """The user frame from markers seen in several views (``landmark_multi``).

    ``observations``: (marker id, T_base_marker (4, 4), covariance (6, 6) in base axes). Ids
    without a nominal pose in ``T_user_marker`` are ignored. The rigid fit is
    :func:`calibrate` ('rigid', with ``max_rms_error`` / ``max_scale_error`` / ``sigma_prior``).
    """
    by_id: dict[int, list[tuple[Array, Array]]] = {}
    for marker_id, T, C in observations:
        T, C = np.asarray(T, dtype=float), np.asarray(C, dtype=float)
        if int(marker_id) in T_user_marker and np.all(np.isfinite(T)):
            if not np.all(np.isfinite(C)):
                C = np.eye(6)
            by_id.setdefault(int(marker_id), []).append((T, C))
    ids = sorted(by_id)
    if not ids:
        return LandmarkFit.failed(LANDMARK_MULTI, Failure(
            ErrorCode.TOO_FEW_POINTS, 'no landmark of the cell was observed'))
    names, pu, pb = [], [], []
    for i in ids:
        views = by_id[i]
        centre, _ = average_centre([T[:3, 3] for T, _ in views],
                                   [C[:3, :3] for _, C in views])
        Tum = np.asarray(T_user_marker[i], dtype=float)
        if len(ids) >= 3:
            names.append(f'L{i}')
            pu.append(Tum[:3, 3])
            pb.append(centre)
        else:           # tie-breaker: the marker's own axes, averaged over its views
            Tbm = np.eye(4)
            Tbm[:3, :3] = _mean_rotation([T[:3, :3] for T, _ in views])
            Tbm[:3, 3] = centre
            names += _names(i)
            pu.extend(_axis_points(Tum))
            pb.extend(_axis_points(Tbm))
    pu, pb = np.array(pu), np.array(pb)
    opts = {} if sigma_prior is None else {'sigma_prior': sigma_prior}
    fit = calibrate('rigid', pu, pb, names=names, max_rms_error=max_rms_error,
                    max_scale_error=max_scale_error, **opts)
    note = (f'{len(ids)} markers, {sum(len(v) for v in by_id.values())} marker observations '
            'averaged')
    if len(ids) < 3:
        note += '; fewer than 3 markers: their orientations fix the frame'
    message = f'{fit.message}; {note}' if fit.message else note
    fit = dataclasses.replace(fit, method=LANDMARK_MULTI, message=message)
    return LandmarkFit(fit, names, pu, pb, {i: len(by_id[i]) for i in ids})
