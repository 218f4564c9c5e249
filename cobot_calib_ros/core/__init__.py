"""Pure calibration math: numpy, scipy, pinocchio, OpenCV. Never imports rclpy or *_msgs."""
