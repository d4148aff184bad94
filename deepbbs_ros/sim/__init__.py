"""Procedural Apollo-style LiDAR drives: scenes, ego trajectories and a spinning-LiDAR ray caster.

No ROS import. Main entry points: :func:`simulate_drive` (an iterator of
:class:`~deepbbs_ros.datasets.base.Scan`) and :class:`DriveSimulator` (random access by frame).
Ray casting uses Embree through the ``embreex`` package.
"""

from deepbbs_ros.sim.lidar import LidarConfig, RayCaster
from deepbbs_ros.sim.scene import SCENES, World
from deepbbs_ros.sim.simulator import DriveSimulator, simulate_drive
from deepbbs_ros.sim.trajectory import Trajectory

#: bumped whenever the worlds a (scene, seed) produces change: caches of simulated drives key on it
WORLDS_VERSION = 2

__all__ = [
    "SCENES", "WORLDS_VERSION", "DriveSimulator", "LidarConfig", "RayCaster", "Trajectory", "World", "simulate_drive",
]
