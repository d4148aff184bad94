"""Procedural Apollo-style LiDAR drives: scenes, ego trajectories and a spinning-LiDAR ray caster.

No ROS import. Main entry points: :func:`simulate_drive` (an iterator of
:class:`~deepbbs_ros.datasets.base.Scan`) and :class:`DriveSimulator` (random access by frame); for
other sensors (Ouster, Hesai, RoboSense, Livox), mounts (wheeled, legged, handheld) and places (indoor,
courtyard, garage): :func:`make_simulator` (``sim/rig.py``). Ray casting uses Embree through the
``embreex`` package.
"""

from deepbbs_ros.sim.lidar import LidarConfig, RayCaster
from deepbbs_ros.sim.mounts import MOUNTS
from deepbbs_ros.sim.patterns import SENSORS, SolidStateConfig, make_sensor
from deepbbs_ros.sim.places import PLACES
from deepbbs_ros.sim.rig import ALL_PLACES, RigSimulator, make_simulator
from deepbbs_ros.sim.scene import SCENES, World
from deepbbs_ros.sim.simulator import DriveSimulator, simulate_drive
from deepbbs_ros.sim.trajectory import Trajectory

#: bumped whenever the worlds a (scene, seed) produces change: caches of simulated drives key on it
WORLDS_VERSION = 3

__all__ = [
    "ALL_PLACES", "MOUNTS", "PLACES", "SCENES", "SENSORS", "WORLDS_VERSION", "DriveSimulator", "LidarConfig",
    "RayCaster", "RigSimulator", "SolidStateConfig", "Trajectory", "World", "make_sensor", "make_simulator",
    "simulate_drive",
]
