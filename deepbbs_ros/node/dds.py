"""The Fast DDS profile shipped for large clouds, and how it is applied by default.

A 120k-point PointCloud2 is ~2.6 MB. Between two processes on this machine, with the default Fast DDS
transports and best-effort QoS, only 2 to 4 of 10 such messages arrived; with the shipped profile
(``deepbbs_ros/resources/fastdds_shm.xml``: shared memory with a 64 MiB segment, plus UDPv4) 10 of 10.
``deepbbs-node``, ``deepbbs-play`` and the launch file therefore point Fast DDS at that profile,
unless the user already chose one. No ROS import here: this runs before rclpy is loaded.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

#: Environment variables Fast DDS reads its XML profiles from (2.x reads the first, 3.x the second).
PROFILE_ENV_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")


def default_profile_path() -> Path:
    """Absolute path of the shipped ``fastdds_shm.xml`` (inside the installed package)."""
    return Path(__file__).resolve().parent.parent / "resources" / "fastdds_shm.xml"


def profile_env(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """The variables to add so that Fast DDS loads the shipped profile; empty if the user set one.

    Also empty when another RMW than Fast DDS is selected (``RMW_IMPLEMENTATION``).
    """
    env = os.environ if environ is None else environ
    if any(env.get(k) for k in PROFILE_ENV_VARS):
        return {}
    rmw = env.get("RMW_IMPLEMENTATION", "")
    if rmw and "fastrtps" not in rmw and "fastdds" not in rmw:
        return {}
    path = str(default_profile_path())
    return {k: path for k in PROFILE_ENV_VARS}


def apply_default_profile(environ: MutableMapping[str, str] | None = None) -> str | None:
    """Set the profile variables in ``environ`` (default ``os.environ``) unless already chosen.

    Must run before the first DDS participant is created (before ``rclpy.init``). Returns the
    profile path when it was applied, else None.
    """
    env = os.environ if environ is None else environ
    extra = profile_env(env)
    env.update(extra)
    return next(iter(extra.values()), None)
