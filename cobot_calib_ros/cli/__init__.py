"""The cobot-calib command line."""
