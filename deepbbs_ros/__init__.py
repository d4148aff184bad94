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

# numpy's, OpenBLAS's and torch's kernels chosen by the CPU (AVX-512 here, AVX2 there) round differently: the AVX2
# ones on every x86-64 CPU that has them, so that answers are the same to the last digit on any computer. Read when
# each library loads, so also set here (deepbbs_ros.cpu_kernels; DEEPBBS_CPU_KERNELS=native opts out).
from deepbbs_ros import cpu_kernels as _cpu_kernels  # noqa: E402

_cpu_kernels.pin()

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
