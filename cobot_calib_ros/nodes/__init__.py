"""Thin rclpy node shells: translate messages, call core, publish."""
