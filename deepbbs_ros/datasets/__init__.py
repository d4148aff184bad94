"""Scan sources (readers) and writers for bags, Apollo-style folders and KITTI folders."""

from deepbbs_ros.datasets.base import APOLLO_LIDAR_FRAME, APOLLO_LIDAR_TOPIC, GT_POSE_TOPIC, WORLD_FRAME, Scan

__all__ = ["APOLLO_LIDAR_FRAME", "APOLLO_LIDAR_TOPIC", "GT_POSE_TOPIC", "WORLD_FRAME", "Scan"]
