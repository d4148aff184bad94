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
def torch_one_thread():
    """One torch thread for the test: tiny models are faster so, and exact-resume comparisons are stable."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def registration_configs(monkeypatch) -> list:
    """The config of every ``DeepBBSRegistration`` built during the test, in order (a spy on its ``__init__``)."""
    from deepbbs_ros.core import registration

    seen: list = []
    init = registration.DeepBBSRegistration.__init__

    def spy(self, config=None, *a, **kw):
        seen.append(config)
        init(self, config, *a, **kw)

    monkeypatch.setattr(registration.DeepBBSRegistration, "__init__", spy)
    return seen


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every test that draws random data is deterministic."""
    random.seed(0)
    return np.random.default_rng(0)


def _street_points(rng: np.random.Generator, n: int, z: float) -> np.ndarray:
    """(n, 3) float32 random points (metres) on one fixed street scene, lifted by ``z``: two facades
    with recesses, a cross wall, poles on a 7 m grid along both kerbs, a car. No ground."""
    u = rng.uniform(size=(n, 3))
    k = n // 6
    parts = [
        np.c_[-30 + 60 * u[:k, 0], np.full(k, 7.0) + 1.5 * (np.sin(u[:k, 0] * 9) > 0.6), 8 * u[:k, 1]],
        np.c_[-30 + 60 * u[k : 2 * k, 0], np.full(k, -8.0) - 2.0 * (np.cos(u[k : 2 * k, 0] * 7) > 0.5),
              6 * u[k : 2 * k, 1]],
        np.c_[np.full(k, 25.0), -8 + 15 * u[2 * k : 3 * k, 0], 5 * u[2 * k : 3 * k, 1]],
    ]  # fmt: skip
    m = n - 4 * k  # poles on a 7 m grid along both kerbs
    pole = rng.integers(0, 16, m)
    ang = 2 * np.pi * u[3 * k : 3 * k + m, 0]
    cx, cy = -26 + 7 * (pole % 8), np.where(pole < 8, 5.0, -6.0)
    parts.append(np.c_[cx + 0.2 * np.cos(ang), cy + 0.2 * np.sin(ang), 4 * u[3 * k : 3 * k + m, 2]])
    box = u[n - k :] * [4.5, 1.8, 1.5]
    face = rng.integers(0, 3, k)
    box[np.arange(k), face] = np.array([4.5, 1.8, 1.5])[face] * rng.integers(0, 2, k)
    parts.append(box + [3.0, -4.0, 0.0])
    return (np.concatenate(parts) + [0.0, 0.0, z]).astype(np.float32)


def _road(rng: np.random.Generator, n: int, z: float) -> np.ndarray:
    """(n, 3) float32 random points on the street's road plane at height ``z``."""
    g = rng.uniform(size=(n, 2))
    return (np.c_[-30 + 60 * g[:, 0], -8 + 15 * g[:, 1], np.zeros(n)] + [0.0, 0.0, z]).astype(np.float32)


def _street(rng: np.random.Generator, n: int, *, road: bool = False) -> list[np.ndarray]:
    """The street scene as ``[non_ground (n, 3)]`` float32, metres, no ground; with ``road=True``
    seen from a sensor 1.9 m above the road: ``[non_ground (n, 3), ground (n // 2, 3)]``."""
    if not road:
        return [_street_points(rng, n, 0.0)]
    return [_street_points(rng, n, -1.9), _road(rng, n // 2, -1.9)]


def _street_pair(seed: int, n: int, euler_zyx_deg, trans, *, road: bool = False):
    """Two independent noisy (0.01 m) samplings of the street; the source seen from ``T_target_source``.

    ``T_target_source`` turns by ``euler_zyx_deg`` (degrees) and shifts by ``trans`` (metres). Returns
    ``(src, tgt, T_target_source)`` with ``src``/``tgt`` (n, 3) float32 clouds; with ``road=True`` the
    sensor sits 1.9 m above the road and each is ``[non_ground (n, 3), ground (n // 2, 3)]``.
    """
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", euler_zyx_deg, degrees=True).as_matrix()
    T[:3, 3] = trans

    def sample() -> list[np.ndarray]:
        return [p + rng.normal(0, 0.01, p.shape).astype(np.float32) for p in _street(rng, n, road=road)]

    tgt, scene = sample(), sample()
    src = [((p - T[:3, 3]) @ T[:3, :3]).astype(np.float32) for p in scene]  # p_source = R^T (p_target - t)
    return (src, tgt, T) if road else (src[0], tgt[0], T)


@pytest.fixture(scope="session")
def street_scene():
    """The street scene builder ``street_scene(rng, n, road=False) -> [non_ground (, ground)]``."""
    return _street


@pytest.fixture(scope="session")
def street_pair():
    """The registration pair builder ``street_pair(seed, n, euler_zyx_deg, trans, road=False)``."""
    return _street_pair


@pytest.fixture(scope="session")
def pair_client():
    """The live pair-mode harness ``pair_client(node, name)`` (:func:`_pair_client`)."""
    return _pair_client


def _pair_client(node, name: str):
    """A client node publishing ``source_cloud`` / ``target_cloud`` (depth 5) and collecting ``/<name>/pose``,
    spun with ``node`` on a 3-thread executor in a daemon thread (real rclpy, DDS): -> (client, poses, pubs,
    executor); the caller shuts the executor down and destroys both nodes."""
    import threading

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.executors import MultiThreadedExecutor
    from sensor_msgs.msg import PointCloud2

    client = rclpy.create_node(f"{name}_client")
    poses: list = []
    client.create_subscription(PoseStamped, f"/{name}/pose", poses.append, 20)
    pubs = {t: client.create_publisher(PointCloud2, t, 5) for t in ("source_cloud", "target_cloud")}
    executor = MultiThreadedExecutor(num_threads=3)
    executor.add_node(node)
    executor.add_node(client)
    threading.Thread(target=executor.spin, daemon=True).start()
    return client, poses, pubs, executor


MAPPING_FRAMES = 24  # the mapping drive: 19 m along the road at 8 m/s, 10 Hz


@pytest.fixture(scope="session")
def day1(tmp_path_factory):
    """The mapping drive (with ground truth) as an mcap recording, and its scans (read only: shared by the modules
    that map or localize in it)."""
    from deepbbs_ros.datasets import write_scans
    from deepbbs_ros.replay.synthetic import synthetic_drive

    scans = synthetic_drive(MAPPING_FRAMES, seed=0, keep=0.25)
    out = tmp_path_factory.mktemp("day1") / "day1"
    write_scans(scans, out, "mcap")
    return out, scans


@pytest.fixture(scope="session")
def site_map(day1, tmp_path_factory):
    """``deepbbs-bag map`` of the mapping drive: site.pcd with its .tum and .png beside it (read only)."""
    from deepbbs_ros.cli.bag import main as bag_main

    out = tmp_path_factory.mktemp("map") / "site.pcd"
    assert bag_main(["map", str(day1[0]), str(out), "--quiet"]) == 0
    return out
