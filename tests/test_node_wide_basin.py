"""Wide basin, live: a source turned by up to 45 deg of yaw and moved up to 5 m still registers, and so does
one turned by 150 or -120 deg and moved 6-8 m (the global search of the default configuration).

The node runs with the shipped weights (pair mode, real rclpy and DDS, one torch thread; the registration in
the node's process, ``node.registration_process`` as shipped).
Target: frame 0 of a simulated urban HDL-64E drive (``deepbbs_ros.sim``, ~120k points, occlusion,
noise, dropouts); source: frame 1 of the same drive (an independent scan 0.1 s later) moved by a
seeded perturbation ``A`` (yaw, horizontal shift), so ``T_target_source' = T_target_source @ inv(A)``.
Each published pose is checked against ground truth (1 deg / 0.3 m) and against
``DeepBBSRegistration.register`` run offline on the same two clouds (the node's config, ``node.deep_passes``
included, and weights): a mismatch there would be the node's, a miss of both would be the model's.
small_gicp GICP from identity on the same pairs is measured for contrast (printed, not asserted: the issue
expects it to manage about a third of such pairs). Run with ``-s`` to see the table.

Measured with the bootstrap weights (step 600): 6 of 6 here, 20 of 20 offline on 20 such perturbations
of urban seeds 5 and 21 (GICP 1 of 20). Not every scene is that easy: on the random-box "town" the node's
tests used before (no occlusion) 7 of 8 offline, one miss at -43.5 deg / 4.1 m (33 deg off), not asserted here.
Frames 0 and 1 of seed 5 are 2.5 cm apart (the car starts): the motion is almost all the perturbation.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")


from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from deepbbs_ros.replay.synthetic import pose  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402


def _shipped_weights_exist() -> bool:
    try:
        from deepbbs_ros.core.checkpoint import default_weights_path
    except ImportError:
        return False
    return default_weights_path().is_file()


pytestmark = pytest.mark.skipif(not _shipped_weights_exist(), reason="shipped weights missing")

SEC = 1_000_000_000
NAME = "deepbbs_wide"
SCENE, SEED = "urban", 5
# (yaw deg, shift m, shift direction rad): the four corners of the basin, then seeded draws inside it
PERTURBATIONS = [(45.0, 5.0, 0.0), (-45.0, 5.0, np.pi / 2), (45.0, 5.0, np.pi), (-45.0, 5.0, -np.pi / 2)]
_rng = np.random.default_rng(1)
PERTURBATIONS += [(_rng.uniform(-45, 45), _rng.uniform(0, 5), _rng.uniform(0, 2 * np.pi)) for _ in range(2)]
# any rotation about z (two sensors with an unknown mounting): outside the network's cone, the global search
PERTURBATIONS += [(150.0, 6.0, 1.0), (-120.0, 8.0, -2.0)]


def _config() -> Config:
    return Config().replace(**{"registration.device": "cpu", "registration.threads": 1})


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_wide_basin_live(ros, pair_client):
    import small_gicp
    import torch

    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.node.parameters import node_registration_config
    from deepbbs_ros.node.registration_node import RegistrationNode
    from deepbbs_ros.sim import simulate_drive

    threads = torch.get_num_threads()
    frames = list(simulate_drive(SCENE, SEED, 2))
    tgt, src0 = frames[0].points, frames[1].points
    T_tgt_src0 = np.linalg.inv(frames[0].T_world_lidar) @ frames[1].T_world_lidar
    node = RegistrationNode(_config(), node_name=NAME)  # loads the shipped weights itself
    client, poses, pubs, executor = pair_client(node, NAME)
    rows = []
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not all(p.get_subscription_count() for p in pubs.values()):
            time.sleep(0.05)
        offline = DeepBBSRegistration(node_registration_config(_config()), weights="")  # node.deep_passes included
        for k, (yaw, shift, direction) in enumerate(PERTURBATIONS):
            A = pose(shift * np.cos(direction), shift * np.sin(direction), 0.0, np.deg2rad(yaw))  # p' = A p
            src = (src0.astype(np.float64) @ A[:3, :3].T + A[:3, 3]).astype(np.float32)
            T_gt = T_tgt_src0 @ np.linalg.inv(A)
            stamp = (10 + k) * SEC
            pubs["target_cloud"].publish(arrays_to_pointcloud2(tgt, stamp_ns=stamp, frame_id="velodyne64"))
            pubs["source_cloud"].publish(arrays_to_pointcloud2(src, stamp_ns=stamp, frame_id="velodyne64"))
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and len(poses) <= k:
                time.sleep(0.02)
            assert len(poses) == k + 1, node.stats()
            T_node, stamp_out, frame = pose_stamped_to_matrix(poses[k])
            assert (stamp_out, frame) == (stamp, "velodyne64")
            T_off = offline.register(src, tgt).T_target_source
            g = small_gicp.align(tgt.astype(np.float64), src.astype(np.float64), downsampling_resolution=0.5,
                                 num_threads=1)
            rows.append((yaw, shift, *pair_errors(T_node, T_gt), *pair_errors(T_off, T_gt),
                         *pair_errors(g.T_target_source, T_gt), T_node, T_off))
        # the node's network passes ran in its worker process (registration.network_process: auto, 2+ cores)
        assert (os.cpu_count() or 1) < 2 or node.reg.network_process_state.startswith("running (pid ")
    finally:
        executor.shutdown()
        node.destroy_node()
        client.destroy_node()
        torch.set_num_threads(threads)
    # destroy_node stopped the network process (on a CPU: with the node's registration process, which owns it)
    assert not node.reg.network_process_state.startswith("running"), node.reg.network_process_state

    def ok(r: float, t: float) -> bool:
        return r <= 1.0 and t <= 0.3

    print(f"\nwide basin, {SCENE} seed {SEED}, frames 0/1, shipped weights (1 torch thread):")
    print(" yaw deg  shift m | node rot deg  trans m | offline rot deg  trans m | GICP rot deg  trans m")
    for yaw, shift, rn, tn, ro, to, rg, tg, *_ in rows:
        print(f" {yaw:7.1f} {shift:8.2f} | {rn:12.3f} {tn:8.3f} | {ro:15.3f} {to:8.3f} | {rg:12.3f} {tg:8.3f}")
    n = len(rows)
    n_node, n_off, n_gicp = (sum(ok(r[i], r[i + 1]) for r in rows) for i in (2, 4, 6))
    print(f" success (1 deg / 0.3 m): node {n_node}/{n}, offline {n_off}/{n}, GICP from identity {n_gicp}/{n}")
    for row in rows:  # the node adds nothing to the registration: same transform as offline
        np.testing.assert_allclose(row[-2], row[-1], rtol=0, atol=1e-6)
    failed = [(round(r[0], 1), round(r[1], 2), round(r[2], 3), round(r[3], 3)) for r in rows if not ok(r[2], r[3])]
    assert not failed, f"outside 1 deg / 0.3 m (yaw, shift, rot deg, trans m): {failed}"
