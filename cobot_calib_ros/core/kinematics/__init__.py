"""Serial-arm kinematics: models and vectorised FK (model), inverse kinematics (ik, pinocchio)."""
from cobot_calib_ros.core.kinematics.ik import IkResult, solve_ik, solve_ik_with_restarts, to_pinocchio
from cobot_calib_ros.core.kinematics.model import (Chain, fk, KinematicModel, model_by_name,
                                                   placement, position_jacobian_wrt_params)

__all__ = ['Chain', 'fk', 'IkResult', 'KinematicModel', 'model_by_name', 'placement',
           'position_jacobian_wrt_params', 'solve_ik', 'solve_ik_with_restarts', 'to_pinocchio']
