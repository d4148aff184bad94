"""One typed configuration shared by the node, the CLIs, training and the YAML files.

The schema is a tree of dataclasses: :class:`Config` has one section per area (``preprocess``,
``model``, ``registration``, ``node``, ``train``, ``eval``). The same tree is

* loaded from YAML (``Config.from_yaml``), either plain sections or a ROS 2 parameter file
  (``<node_name>: ros__parameters: {...}`` or ``/**: ros__parameters: {...}``; ``config/deepbbs_ros.yaml``
  is one, keyed ``/**`` so that it applies to the node under any name),
* declared as ROS parameters with dotted names (``preprocess.voxel_size``) via
  :meth:`Config.to_flat` / :meth:`Config.from_flat`,
* saved next to every result (``Config.to_dict``) and inside checkpoints.

Units are SI (metres, seconds); angles are radians unless the name ends in ``_deg``.
Unknown keys, wrong types and out-of-range values raise :class:`~deepbbs_ros.errors.ConfigError`
naming the offending key.

One module per group of sections, each class with its fields (a comment each: the docs' parameter tables,
:mod:`deepbbs_ros.config_doc`) and its ``validate``: ``preprocess.py``, ``registration.py`` (``model``,
``registration``), ``node.py``, ``odometry.py``, ``localization.py``, ``offline.py`` (``train``, ``eval``);
``root.py`` the :class:`Config` tree and its conversions, ``keys.py`` the checks' helper and the did-you-mean.
"""

from __future__ import annotations

from deepbbs_ros.config.keys import did_you_mean, nearest_keys
from deepbbs_ros.config.localization import LocalizationConfig
from deepbbs_ros.config.node import NodeConfig
from deepbbs_ros.config.odometry import OdometryConfig
from deepbbs_ros.config.offline import EvalConfig, TrainConfig
from deepbbs_ros.config.preprocess import PreprocessConfig
from deepbbs_ros.config.registration import ModelConfig, RegistrationConfig
from deepbbs_ros.config.root import Config, load_config

__all__ = [
    "Config",
    "EvalConfig",
    "LocalizationConfig",
    "ModelConfig",
    "NodeConfig",
    "OdometryConfig",
    "PreprocessConfig",
    "RegistrationConfig",
    "TrainConfig",
    "did_you_mean",
    "load_config",
    "nearest_keys",
]
