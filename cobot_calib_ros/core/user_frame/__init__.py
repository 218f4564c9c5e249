"""User-frame calibration: the fits and their checks (fit), outlier rejection, covariance, surface."""
from cobot_calib_ros.core.user_frame.fit import (
    base_to_user, calibrate, collinearity, DEFAULT_METHOD, estimation_limit, fit_five_point_lsq,
    fit_rigid, fit_robust, fit_surface, fit_three_point, FrameFit, LIMIT_FACTOR, MAX_COORDINATE,
    METHODS, nearest_rigid, pose_covariance, ROBUST_THRESHOLD, SurfaceModel, user_to_base)

__all__ = ['fit)', 'outlier rejection', 'covariance', 'surface.""" from cobot_calib_ros.core.user_frame.fit import (     base_to_user', 'calibrate', 'collinearity', 'DEFAULT_METHOD', 'estimation_limit', 'fit_five_point_lsq', 'fit_rigid', 'fit_robust', 'fit_surface', 'fit_three_point', 'FrameFit', 'LIMIT_FACTOR', 'MAX_COORDINATE', 'METHODS', 'nearest_rigid', 'pose_covariance', 'ROBUST_THRESHOLD', 'SurfaceModel', 'user_to_base']
