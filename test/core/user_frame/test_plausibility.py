"""core.user_frame.check_plausible and calibrate()'s gate: fits that no touched frame can have."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import user_frame as uf
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.frames import apply, from_xyz_rpy

# The first paper's "close" layout (user frame, z = 0.02 m) and the cell's true user frame.
CLOSE5 = np.array([[0.15, 0.10, 0.02], [0.35, 0.10, 0.02], [0.35, 0.25, 0.02],
                   [0.15, 0.25, 0.02], [0.25, 0.175, 0.02]])
T_CELL = from_xyz_rpy([0.35, -0.05, 0.0], [0.002, -0.0015, 0.03])


def measured(noise: float = 2e-5, seed: int = 0) -> np.ndarray:
    return apply(T_CELL, CLOSE5) + np.random.default_rng(seed).normal(0.0, noise, CLOSE5.shape)


def test_the_users_case_base_in_millimetres_is_refused() -> None:
    """Base points in mm, user points in m: the rigid fit "succeeded" with RMS 111.7 m and
    became the active calibration. Now calibrate() refuses it and says why."""
    p_base = measured() * 1e3
    fit = uf.calibrate('rigid', CLOSE5, p_base)
    assert not fit and fit.code == ErrorCode.IMPLAUSIBLE_FIT and fit.T_base_user is None
    assert fit.message.startswith('RMS residual 111.7 m > max_rms_error 0.01 m')
    assert 'are base points in millimetres and user points in metres' in fit.message
    ungated = uf.calibrate('rigid', CLOSE5, p_base, max_rms_error=None)
    assert ungated and ungated.rms == pytest.approx(111.7, abs=0.05)   # what the user got


@pytest.mark.parametrize('method', uf.METHODS)
@pytest.mark.parametrize('user_scale, base_scale', [(1.0, 1e3), (1e3, 1.0)],
                         ids=['base_mm', 'user_mm'])
def test_a_units_mix_is_refused_by_every_method(method: str, user_scale: float,
                                                 base_scale: float) -> None:
    fit = uf.calibrate(method, CLOSE5 * user_scale, measured() * base_scale)
    assert not fit and fit.code == ErrorCode.IMPLAUSIBLE_FIT, fit.message
    assert 'millimetres' in fit.message and 'Give both in metres' in fit.message


def test_the_affine_scale_says_which_set_is_in_millimetres() -> None:
    """five_point_lsq absorbs the factor 1000 into M: tiny residuals, scale 1000."""
    ungated = uf.calibrate('five_point_lsq', CLOSE5, measured() * 1e3, max_rms_error=None)
    assert ungated and ungated.rms < 1e-1 and ungated.scale[0] == pytest.approx(1e3, rel=1e-3)
    base_mm = uf.check_plausible(ungated, 1e-3)
    assert base_mm is not None and base_mm.code == ErrorCode.IMPLAUSIBLE_FIT
    assert 'base points are 1000 times the size' in base_mm.message
    user_mm = uf.check_plausible(uf.fit_five_point_lsq(CLOSE5 * 1e3, measured()), 1e-3)
    assert user_mm is not None and 'are user points in millimetres' in user_mm.message


def test_a_scale_error_beyond_the_limit_that_is_no_units_mix() -> None:
    stretched = CLOSE5.copy()
    stretched[:, 0] *= 1.02                         # the measured layout 2 % longer in x
    fit = uf.fit_five_point_lsq(CLOSE5, apply(T_CELL, stretched))
    assert fit and fit.scale[0] == pytest.approx(1.02, abs=1e-9)
    failure = uf.check_plausible(fit, 1e-3)
    assert failure is not None and failure.code == ErrorCode.IMPLAUSIBLE_FIT
    assert 'off 1 by 0.02 > max_scale_error 0.01' in failure.message
    assert 'not the nominal one' in failure.message and 'millimetres' not in failure.message
    assert uf.check_plausible(fit, 1e-3, max_scale_error=0.05) is None


def test_rms_and_largest_residual_limits_name_the_point() -> None:
    p_base = measured()
    p_base[4] += T_CELL[:3, 0] * 2e-3               # the centre P5 touched 2 mm off in x
    fit = uf.fit_rigid(CLOSE5, p_base)
    assert fit and 0.5e-3 < fit.rms < 1e-3 and 1e-3 < fit.max_residual < 3e-3
    assert uf.check_plausible(fit, 1e-3) is None    # max within the default 3 x 1 mm
    rms = uf.check_plausible(fit, 0.5e-3)
    assert rms is not None and rms.message.startswith('RMS residual 0.000')
    assert 'same order' in rms.message and 'millimetres' not in rms.message
    names = ['A1', 'B1', 'C1', 'D1', 'centre']
    largest = uf.check_plausible(fit, 1e-3, max_residual_error=1e-3, names=names)
    assert largest is not None and largest.code == ErrorCode.IMPLAUSIBLE_FIT
    assert 'at centre > max_residual_error 0.001 m (1 mm)' in largest.message
    assert 're-touch centre' in largest.message
    assert 'at P5 >' in uf.check_plausible(fit, 1e-3, max_residual_error=1e-3).message
    gated = uf.calibrate('rigid', CLOSE5, p_base, names=names, max_rms_error=0.5e-3)
    assert not gated and gated.code == ErrorCode.IMPLAUSIBLE_FIT


def test_a_good_fit_passes_and_a_failed_fit_keeps_its_failure() -> None:
    fit = uf.calibrate('rigid', CLOSE5, measured())
    assert fit and uf.check_plausible(fit, 1e-3) is None
    collinear = uf.fit_rigid(CLOSE5[[0, 1, 0]] + [[0, 0, 0], [0, 0, 0], [0.1, 0, 0]],
                             measured()[:3])
    failure = uf.check_plausible(collinear, 1e-3)
    assert failure is not None and failure.code == collinear.code != ErrorCode.SUCCESS
    assert failure.message == collinear.message


def test_robust_outliers_do_not_count_as_the_largest_residual() -> None:
    p_base = measured(seed=3)
    p_base[1] += T_CELL[:3, 0] * 4e-3               # in-plane: a height error is ambiguous
    fit = uf.fit_robust(CLOSE5, p_base)
    assert fit and fit.outliers == (1,) and np.linalg.norm(fit.residuals[1]) > 3e-3
    assert uf.check_plausible(fit, 1e-3, max_residual_error=1e-3) is None


def test_limits_must_be_positive() -> None:
    fit = uf.calibrate('rigid', CLOSE5, measured())
    for limits in [(0.0,), (1e-3, -0.01), (1e-3, 0.01, -1.0)]:
        kwargs = {'max_residual_error': limits[2]} if len(limits) == 3 else {}
        with pytest.raises(ValueError, match='> 0'):
            uf.check_plausible(fit, *limits[:2], **kwargs)


@pytest.mark.parametrize('method', uf.METHODS)
def test_both_point_sets_in_millimetres_are_named_as_such(method: str) -> None:
    """Issue 23.7: both sets in mm fit with a tiny scale error and a 1000x residual, and got
    're-touch the points'."""
    fit = uf.calibrate(method, CLOSE5 * 1e3, measured() * 1e3)
    assert not fit and fit.code == ErrorCode.INVALID_INPUT
    assert fit.message.startswith('the points look like millimetres (user points up to 350, '
                                  'base points up to 6')
    assert 'lengths are in metres' in fit.message and 're-touch' not in fit.message


def test_an_unknown_method_is_named_before_anything_else() -> None:
    """Issue 23.7: {method: bogus} without points got 'no points'; the node checks the method
    first with method_problem (landmark methods included)."""
    from cobot_calib_ros.core.user_frame.landmarks import CALIBRATION_METHODS, method_problem
    assert CALIBRATION_METHODS == ('three_point', 'five_point_lsq', 'rigid', 'robust',
                                   'landmark_single', 'landmark_multi')
    failure = method_problem('bogus')
    assert failure.code == ErrorCode.UNKNOWN_METHOD
    assert failure.message == ("unknown method 'bogus'; one of: three_point, five_point_lsq, "
                               'rigid, robust, landmark_single, landmark_multi')
    assert all(method_problem(m) is None for m in ('', *CALIBRATION_METHODS))
