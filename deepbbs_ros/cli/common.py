"""Shared CLI plumbing: known errors become one line and exit code 1 (:func:`cli_entry`, defined in
:mod:`deepbbs_ros.entry` so that the node shares it without importing the CLI layer); DDS stays on
loopback (:func:`local_ros_env`)."""

from __future__ import annotations

import os

from deepbbs_ros.entry import cli_entry

__all__ = ["cli_entry", "local_ros_env"]


def local_ros_env(domain_id: int | None = None) -> None:
    """Keep DDS discovery on loopback and in a run-specific domain, unless the user chose one.

    Used by everything that starts DDS on its own (tests, demo, benchmarks); not by the live node,
    which follows the robot's environment.
    """
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id if domain_id is not None else 1 + os.getpid() % 100)
