"""cobot_calib_ros: live calibration of a collaborative-robot cell on ROS 2 Jazzy."""
