"""User-frame calibration: the methods and calibrate() (fit), outlier rejection (robust), pose
covariance and estimation limit (covariance), height correction (surface), sanity gate
(plausibility); input checks (checks), pose estimators (estimators) and their derivatives
(jacobians), FrameFit (result)."""
from cobot_calib_ros.core.user_frame.checks import MAX_COORDINATE, point_names
from cobot_calib_ros.core.user_frame.covariance import (
    estimation_limit, LIMIT_FACTOR, pose_covariance)
from cobot_calib_ros.core.user_frame.estimators import DEFAULT_METHOD, METHODS, nearest_rigid
from cobot_calib_ros.core.user_frame.fit import (
    calibrate, fit_five_point_lsq, fit_rigid, fit_three_point)
from cobot_calib_ros.core.user_frame.geometry import collinearity
from cobot_calib_ros.core.user_frame.plausibility import (
    check_plausible, MAX_RESIDUAL_FACTOR, MAX_RMS_ERROR, MAX_SCALE_ERROR, SCALE_FALSE_REFUSAL,
    scale_significance)
from cobot_calib_ros.core.user_frame.result import FrameFit
from cobot_calib_ros.core.user_frame.robust import (
    fit_robust, MIN_INLIERS, ROBUST_FALSE_REJECTION, ROBUST_THRESHOLD)
from cobot_calib_ros.core.user_frame.surface import (
    base_to_user, fit_surface, SurfaceModel, user_to_base)

__all__ = [
    'base_to_user', 'calibrate', 'check_plausible', 'collinearity', 'DEFAULT_METHOD',
    'estimation_limit', 'fit_five_point_lsq', 'fit_rigid', 'fit_robust', 'fit_surface',
    'fit_three_point', 'FrameFit', 'LIMIT_FACTOR', 'MAX_COORDINATE', 'MAX_RESIDUAL_FACTOR',
    'MAX_RMS_ERROR', 'MAX_SCALE_ERROR', 'METHODS', 'MIN_INLIERS', 'nearest_rigid',
    'point_names', 'pose_covariance', 'ROBUST_FALSE_REJECTION', 'ROBUST_THRESHOLD',
    'SCALE_FALSE_REFUSAL', 'scale_significance', 'SurfaceModel', 'user_to_base']
