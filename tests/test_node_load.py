"""Load: both inputs at 20 Hz with 120k-point clouds for 60 s into the node running as a subprocess.

Checks: bounded synchroniser queues, RSS growth of the node process <= 50 MB after warm-up, every pair
registered or, when the registration falls behind, stale clouds and pairs dropped and counted, and every published
pose correct for its stamps. The node loads a tiny random checkpoint and runs the refinement only
(``registration.deep: false``) on small motions: what is tested is the node under load, not the
network. This test takes ~75 s on purpose (the issue asks for >= 60 s).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")
pytest.importorskip("deepbbs_ros.core.registration", reason="core registration not available")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.qos import qos_profile_sensor_data  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from deepbbs_ros.replay.synthetic import MOUNT_HEIGHT, pose, scan_at, structured_world  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import ns_to_stamp, pose_stamped_to_matrix  # noqa: E402

DURATION_S = 62.0
WARMUP_S = 12.0
RATE_HZ = 20.0
N_POINTS = 120_000
N_PAIRS = 6  # distinct (target, source) clouds cycled by stamp index
SEC = 1_000_000_000
NAME = "deepbbs_load"


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


def _write_tiny(tmp: Path) -> Path:
    import torch

    from deepbbs_ros.core.checkpoint import save_checkpoint
    from deepbbs_ros.core.model import DeepBBSNet

    cfg = Config().replace(**{
        "model.k": 8, "model.dgcnn_widths": [16, 32], "model.emb_dims": 32, "model.n_heads": 2,
        "model.ff_dims": 64, "preprocess.num_points": 512, "registration.deep": False,
        "registration.refine": True, "registration.polish": "none",
        "registration.device": "cpu", "node.queue_size": 5,
        "node.slop": 0.01,  # both inputs carry identical stamps 50 ms apart: never pair neighbours
    })
    torch.manual_seed(0)
    weights = save_checkpoint(tmp / "tiny.pt", DeepBBSNet(cfg.model).eval(), cfg, {"note": "random, for tests"})
    cfg = cfg.replace(**{"registration.weights": str(weights)})
    cfg.to_yaml(tmp / "tiny.yaml", node_name=NAME)
    return tmp / "tiny.yaml"


def test_load_20hz_120k_for_60s(tmp_path):
    world = structured_world(11, length=130.0, density=5.0)  # ~150k points within 60 m of each pose
    T_gt = [pose(0.3 + 0.15 * m, -0.2 + 0.1 * m, 0.0, np.deg2rad(-2.0 + 0.8 * m)) for m in range(N_PAIRS)]
    msgs = []
    for m in range(N_PAIRS):
        T_w_tgt = pose(8.0 * m, 0.0, MOUNT_HEIGHT, 0.2 * m)
        tgt_xyz = scan_at(world, T_w_tgt, np.random.default_rng(2 * m), n_points=N_POINTS)
        src_xyz = scan_at(world, T_w_tgt @ T_gt[m], np.random.default_rng(2 * m + 1), n_points=N_POINTS)
        tgt = arrays_to_pointcloud2(tgt_xyz, frame_id="lidar")
        src = arrays_to_pointcloud2(src_xyz, frame_id="lidar")
        msgs.append((src, tgt))
    cfg_path = _write_tiny(tmp_path)

    rclpy.init()
    client = rclpy.create_node("load_client")
    poses: list[PoseStamped] = []
    diags: list[DiagnosticArray] = []
    client.create_subscription(PoseStamped, f"/{NAME}/pose", poses.append, 100)
    client.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 100)
    pub_s = client.create_publisher(PointCloud2, "source_cloud", qos_profile_sensor_data)
    pub_t = client.create_publisher(PointCloud2, "target_cloud", qos_profile_sensor_data)
    proc = subprocess.Popen(
        [sys.executable, "-m", "deepbbs_ros.node.registration_node", "--config", str(cfg_path),
         "--ros-args", "-r", f"__node:={NAME}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    rss = {}
    try:
        deadline = time.monotonic() + 60
        while pub_s.get_subscription_count() == 0 or pub_t.get_subscription_count() == 0:
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "node did not subscribe"
            rclpy.spin_once(client, timeout_sec=0.1)
        t0 = time.monotonic()
        k = 0
        while True:
            now = time.monotonic() - t0
            if now >= DURATION_S:
                break
            if "warm" not in rss and now >= WARMUP_S:
                rss["warm"] = _rss_mb(proc.pid)
            due = k / RATE_HZ
            if now >= due:
                src, tgt = msgs[k % N_PAIRS]
                stamp = ns_to_stamp(1000 * SEC + k * SEC // int(RATE_HZ))
                src.header.stamp = stamp
                tgt.header.stamp = stamp
                pub_t.publish(tgt)
                pub_s.publish(src)
                k += 1
            rclpy.spin_once(client, timeout_sec=max(0.0, min(0.01, due + 1 / RATE_HZ - now)))
        rss["end"] = _rss_mb(proc.pid)
        end = time.monotonic() + 15
        while time.monotonic() < end:
            rclpy.spin_once(client, timeout_sec=0.1)
            if diags and time.monotonic() > end - 12:
                break
        assert proc.poll() is None, "node died under load"
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
        client.destroy_node()
        rclpy.try_shutdown()
    assert proc.returncode in (0, -15), err

    values = {kv.key: kv.value for kv in diags[-1].status[0].values}
    processed = int(values["pairs processed"])
    dropped = int(values["pairs dropped (newest wins)"])
    dropped_clouds = [int(n) for n in values["clouds dropped before preprocessing (oldest first)"].split(",")]
    print(f"sent {k} pairs, processed {processed}, pairs dropped {dropped}, clouds dropped {dropped_clouds}, "
          f"poses {len(poses)}, rss {rss}")
    assert k >= DURATION_S * RATE_HZ * 0.95
    # it kept up with 20 Hz, or what it could not register was dropped and counted: stale clouds (waiting for
    # preprocessing) or pairs (waiting for registration); the input threads preprocess at most one pair ahead of
    # the registration (since the inputs leave the sampling to its first use this node keeps up on 2 cores; the
    # drop policy under a slower registration: test_node.py's busy-node test)
    assert processed >= 0.95 * k or dropped + sum(dropped_clouds) > 0, values
    assert processed >= 10 and len(poses) >= 10
    assert all(int(n) <= 5 for n in values["sync queue lengths"].split(","))  # bounded per input
    assert rss["end"] - rss["warm"] <= 50.0, rss
    stamps = set()
    for msg in poses:
        T, stamp, frame = pose_stamped_to_matrix(msg)
        idx = (stamp - 1000 * SEC) * int(RATE_HZ) // SEC
        rot, trans = pair_errors(T, T_gt[idx % N_PAIRS])
        assert rot <= 1.0 and trans <= 0.3, (idx, rot, trans)
        assert frame == "lidar" and stamp not in stamps
        stamps.add(stamp)
