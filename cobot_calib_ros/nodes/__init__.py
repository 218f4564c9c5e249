"""Thin rclpy node shells: translate messages, call core, publish."""

# The node registry, in launch order (api.launcher starts them so; setup.py makes one console
# script per entry, reading this literal without importing the package).
NODES = ('mock_robot', 'joint_state_monitor', 'proximity_sensor', 'user_frame_solver',
         'repeatability_trial', 'kinematic_identifier', 'mock_camera', 'landmark_detector',
         'hand_eye_calibrator', 'tcp_calibrator', 'camera_calibrator', 'robot_adapter')
# Started only with `up --robot-interface driver` (mock_robot then a ros2_control-like driver),
# or by hand beside a real arm's driver: not in the default suite (api.launcher.SUITE).
DRIVER_NODES = ('robot_adapter',)
