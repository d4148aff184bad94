"""Shared test setup: DDS on loopback with a per-run domain, deterministic seeds, shared builders."""

from __future__ import annotations

import os
import random

import numpy as np
import pytest

# Everything that may start DDS stays on loopback and in a domain of its own, so parallel runs
# (and other sessions on this machine) never see each other. Set before rclpy is imported.
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
if "DEEPBBS_TEST_DOMAIN_ID" in os.environ:
    os.environ["ROS_DOMAIN_ID"] = os.environ["DEEPBBS_TEST_DOMAIN_ID"]
else:
    os.environ["ROS_DOMAIN_ID"] = str(1 + (os.getpid() % 100))


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every test that draws random data is deterministic."""
    random.seed(0)
    return np.random.default_rng(0)
