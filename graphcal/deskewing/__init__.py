"""Deskew (seed 002): each revolution in its end-of-scan lidar frame, from the INS or wheel odometry."""
