"""Serial-arm kinematics: models and vectorised FK (model), inverse kinematics (ik, pinocchio)."""
from cobot_calib_ros.core.kinematics.ik import IkResult, solve_ik, solve_ik_with_restarts, to_pinocchio
from cobot_calib_ros.core.kinematics.model import (Chain, fk, KinematicModel, placement,
                                                   position_jacobian_wrt_params)
from cobot_calib_ros.core.kinematics.robots import model_by_name, model_for, ROBOTS, UrdfRobot

__all__ = ['Chain', 'fk', 'IkResult', 'KinematicModel', 'model_by_name', 'model_for',
           'placement', 'position_jacobian_wrt_params', 'ROBOTS', 'solve_ik',
           'solve_ik_with_restarts', 'to_pinocchio', 'UrdfRobot']
