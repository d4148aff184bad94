"""deepbbs_ros: DeepBBS++ LiDAR registration for ROS 2 (Jazzy).

The core (``deepbbs_ros.core``, ``deepbbs_ros.sim``, ``deepbbs_ros.datasets``, ``deepbbs_ros.metrics``)
has no ROS import; ``msg_adapters`` converts messages and ``deepbbs_ros.node`` is the thin rclpy layer.
Importing this package is cheap: heavy modules (torch, rclpy) are imported where they are used.
"""

__version__ = "0.1.0"

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
