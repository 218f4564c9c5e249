"""Kinematic parameter identification: one engine for live data and measurement files.

Measurements of four kinds with their residuals and Jacobians (measurements, tip_jacobian),
the error models, identifiability, the bounded solve and cross-validation (measurement_fit:
``calibrate`` is the call every path ends in), the gates (gates), joint compliance
(compliance); live data (observations: sphere couplings, a laser tracker), the tool centre and
the tool-position Jacobian planning predicts with (parameters), absolute validation and the
paper's tables (validation), the Algorithm 2 pose grid (poses).
"""
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import (
    ParameterSet, TOOL_NAMES, tool_frames, tool_kinematics, tool_transform)
from cobot_calib_ros.core.kinematics.identification.poses import (
    lock_joint, PAPER_ANGLES_DEG, Pose, PoseGrid, sphere_pose_grid, Unreachable)
from cobot_calib_ros.core.kinematics.identification.validation import (
    absolute_errors, error_stats, register_rigid, table6)

__all__ = [
    'absolute_errors', 'error_stats', 'lock_joint', 'PAPER_ANGLES_DEG', 'ParameterSet', 'Pose',
    'PoseGrid', 'PositionObservations', 'register_rigid', 'sphere_pose_grid',
    'SphereObservations', 'table6', 'TOOL_NAMES', 'tool_frames', 'tool_kinematics',
    'tool_transform', 'Unreachable']
