"""Kinematic parameter identification (KUKA iiwa sphere-coupling paper, sections 2.3-4.3).

Free parameters (parameters), Algorithm 1 (identifiability), data (observations), residuals
with analytic Jacobians (objectives), identify() (solvers), absolute validation and the
paper's tables (validation), the Algorithm 2 pose grid (poses).
"""
from cobot_calib_ros.core.kinematics.identification.identifiability import (
    base_motion_columns, Dropped, find_redundant, Identifiability, uniform_configurations)
from cobot_calib_ros.core.kinematics.identification.objectives import (
    AbsoluteObjective, all_pairs, CentresObjective, PairsObjective)
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import (
    default_candidates, ParameterSet, TOOL_NAMES, tool_frames, tool_kinematics, tool_transform)
from cobot_calib_ros.core.kinematics.identification.poses import (
    lock_joint, PAPER_ANGLES_DEG, Pose, PoseGrid, sphere_pose_grid, Unreachable)
from cobot_calib_ros.core.kinematics.identification.solvers import (
    identify, IdentificationResult, LOSSES, SOLVERS)
from cobot_calib_ros.core.kinematics.identification.validation import (
    absolute_errors, error_stats, register_rigid, table6)

__all__ = [
    'absolute_errors', 'AbsoluteObjective', 'all_pairs', 'base_motion_columns', 'CentresObjective',
    'default_candidates', 'Dropped', 'error_stats', 'find_redundant', 'identify',
    'IdentificationResult', 'Identifiability', 'lock_joint', 'LOSSES', 'PairsObjective',
    'PAPER_ANGLES_DEG', 'ParameterSet', 'Pose', 'PoseGrid', 'PositionObservations',
    'register_rigid', 'SOLVERS', 'sphere_pose_grid', 'SphereObservations', 'table6',
    'TOOL_NAMES', 'tool_frames', 'tool_kinematics', 'tool_transform', 'uniform_configurations',
    'Unreachable']
