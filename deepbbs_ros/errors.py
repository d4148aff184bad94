"""One exception hierarchy for the whole package.

Every error the package raises on purpose is a :class:`DeepBBSError`; each area has its own subclass.
Messages name the offending thing (file, line, field, parameter). CLIs turn these into one line and
exit code 1; unknown exceptions keep their traceback.
"""


class DeepBBSError(Exception):
    """Base class of every error deepbbs_ros raises on purpose."""


class ConfigError(DeepBBSError, ValueError):
    """Invalid configuration: unknown key, wrong type, value out of range, unreadable YAML."""


class PointCloudFormatError(DeepBBSError, ValueError):
    """A PointCloud2 message (or numpy layout) that cannot be decoded or encoded."""


class TransformFormatError(DeepBBSError, ValueError):
    """A matrix, quaternion, stamp or flavour that cannot become (or come from) a ROS message."""


class DatasetError(DeepBBSError):
    """A recording or dataset folder that cannot be read or written (PCD, pose file, KITTI)."""


class BagError(DatasetError):
    """A ROS 1 / ROS 2 bag or mcap file that cannot be read or written (truncated, no topic, ...)."""


class ModelError(DeepBBSError):
    """A checkpoint that is missing, corrupt or does not match the model configuration."""


class RegistrationError(DeepBBSError):
    """Registration cannot run on the given input (empty cloud, too few points, NaNs)."""


class SimulationError(DeepBBSError):
    """The LiDAR simulator was asked for something it cannot do."""


class NodeError(DeepBBSError):
    """The ROS node cannot start or run (bad parameter, bad topic name, unknown device)."""


class LocalizationError(DeepBBSError, ValueError):
    """Localization in a prior map cannot run on the given input (empty map, unreadable map file, a scan too small)."""


class VerdictModelError(DeepBBSError):
    """The calibrated verdict's coefficients (deepbbs_ros/resources/verdict_model.json) are missing or unreadable."""
