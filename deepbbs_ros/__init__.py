"""deepbbs_ros: DeepBBS++ LiDAR registration for ROS 2 (Jazzy).

The core (``deepbbs_ros.core``, ``deepbbs_ros.sim``, ``deepbbs_ros.datasets``, ``deepbbs_ros.metrics``)
has no ROS import; ``msg_adapters`` converts messages and ``deepbbs_ros.node`` is the thin rclpy layer.
Importing this package is cheap: heavy modules (torch, rclpy) are imported where they are used.
"""

import os as _os

__version__ = "0.1.0"

# OpenMP threads (torch's and small_gicp's) that finish a parallel region spin-wait for the next one by
# default. On a robot's busy computer another process holds a core, the spinning threads compete with
# the one doing work, and every parallel region waits for a descheduled thread: measured here with one
# background training process on the 2 cores, a DeepBBS++ embedding went from 41 ms to 1.5 s. Passive
# waiting (threads sleep) avoids that; it is read once, when the OpenMP runtime loads (the first torch
# or small_gicp import), so it is set here, before either. A user's own OMP_WAIT_POLICY wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from deepbbs_ros.errors import (  # noqa: E402
    BagError,
    ConfigError,
    DatasetError,
    DeepBBSError,
    ModelError,
    NodeError,
    PointCloudFormatError,
    RegistrationError,
    SimulationError,
    TransformFormatError,
)

__all__ = [
    "__version__",
    "BagError",
    "ConfigError",
    "DatasetError",
    "DeepBBSError",
    "ModelError",
    "NodeError",
    "PointCloudFormatError",
    "RegistrationError",
    "SimulationError",
    "TransformFormatError",
]
