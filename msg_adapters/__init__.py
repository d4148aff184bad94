"""Conversions between ROS messages and numpy (no rclpy/rosbags import at module level)."""
