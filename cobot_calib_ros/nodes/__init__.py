"""Thin rclpy node shells: translate messages, call core, publish."""

# The node registry, in launch order (api.launcher starts them so; setup.py makes one console
# script per entry, reading this literal without importing the package).
NODES = ('mock_robot', 'joint_state_monitor', 'proximity_sensor', 'user_frame_solver',
         'repeatability_trial', 'kinematic_identifier', 'mock_camera', 'landmark_detector',
         'hand_eye_calibrator')
