"""The GICP anchor node ``gicp_anchor``: the live node with small_gicp GICP in place of DeepBBS++.

The same inputs, outputs, modes, threads and drop policy as ``deepbbs-node``
(:class:`~deepbbs_ros.node.registration_node.RegistrationNode`); only the registration differs:
:class:`deepbbs_ros.baselines.SmallGicpRegistration` ``("gicp", config)`` from identity, scan to scan
(``eval.baseline_*`` keys: voxel grid, neighbours, correspondence distance, iterations; the threads of the
DeepBBS++ node's precision stage, ``registration.polish_threads``); with a latched map (``node.target_mode:
latched``, ``node.initial_pose``) each scan is registered on the map's crop from the last answer. It
is the baseline that latency and accuracy figures of the node are reported against, measured on the
same machine in the same minute (``scripts/benchmarks/node_latency.py``).

    python -m deepbbs_ros.node.gicp_anchor [--config YAML] --ros-args -p node.mode:=odometry -r cloud:=/points
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.entry import cli_entry
from deepbbs_ros.node.registration_node import RegistrationNode
from deepbbs_ros.node.run import run_node

ANCHOR_NAME = "gicp_anchor"


@dataclass
class PreparedGicpCloud:
    """A cloud prepared for GICP (:class:`deepbbs_ros.baselines.PreparedCloud`) in the node's interface."""

    prepared: Any

    @property
    def points(self) -> np.ndarray:
        """(M, 3) float32 downsampled points, sensor frame (the residuals behind ``~/odometry``'s covariance)."""
        return np.asarray(self.prepared.cloud.points(), dtype=np.float32)[:, :3]


class GicpRegistration:
    """small_gicp GICP with the node's registration interface: ``preprocess(xyz)``, ``register(src, tgt)``.

    Args:
        config: the package config (``preprocess`` crop ranges, ``eval.baseline_*``).
    """

    weights = "none (small_gicp GICP anchor)"
    device = "cpu"

    def __init__(self, config: Config) -> None:
        from deepbbs_ros.baselines import SmallGicpRegistration

        self.gicp = SmallGicpRegistration("gicp", config, threads=config.registration.polish_threads)

    def preprocess(self, points: np.ndarray, times: np.ndarray | None = None,
                   stamp_ns: int | None = None) -> PreparedGicpCloud:
        """(N, 3) float32 raw scan -> voxel grid, k-d tree and covariances; RegistrationError when too few points.
        Per-point times are not used: the anchor is small_gicp as it comes (no deskew)."""
        return PreparedGicpCloud(self.gicp.preprocess(points))

    def register(self, source: PreparedGicpCloud, target: PreparedGicpCloud,
                 T_init: np.ndarray | None = None) -> Any:
        """``T_target_source`` (a :class:`deepbbs_ros.baselines.BaselineResult`) from ``T_init`` (4, 4)
        ``T_target_source`` (identity when None): a latched map (``node.target_mode: latched``) is tracked from
        the last answer, as the node's localization tracks its map."""
        return self.gicp.align(source.prepared, target.prepared, T_init)


def make_anchor_node(config: Config, **node_kwargs: Any) -> RegistrationNode:
    """The anchor node (``rclpy.init`` must have been called); odometry mode chains GICP scan to scan
    (``odometry_method="scan_to_scan"``), the baseline the node's odometry is measured against."""
    node_kwargs.setdefault("node_name", ANCHOR_NAME)
    node_kwargs.setdefault("odometry_method", "scan_to_scan")
    return RegistrationNode(config, registration=GicpRegistration(config), **node_kwargs)


@cli_entry("deepbbs-gicp-node")
def main(argv: list[str] | None = None) -> int:
    """``python -m deepbbs_ros.node.gicp_anchor [--config YAML] [--ros-args ...]``: run until Ctrl-C."""
    return run_node(argv, "deepbbs-gicp-node", "small_gicp GICP anchor node (the topics of deepbbs-node).",
                    make_anchor_node)  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
