"""The live node with a map moved after it was made, its old trajectory beside it (real rclpy over real DDS): one
warning says the trajectory does not fit and the node places scans with the map's own places; no internal error
reaches the log."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
from test_node import Harness  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.core.checkpoint import default_weights_path  # noqa: E402
from deepbbs_ros.core.mapping import build_map  # noqa: E402
from deepbbs_ros.datasets.maps import write_map  # noqa: E402
from deepbbs_ros.replay.synthetic import synthetic_drive  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context


def test_moved_map_warns_once_and_localizes_without_internal_error(ros, tmp_path, capfd):
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    from deepbbs_ros.core.registration import DeepBBSRegistration

    scans = synthetic_drive(24, seed=0, keep=0.25)
    built = build_map(scans, Config(), voxel=0.2, source="truth", has_ground_truth=True)
    M = np.eye(4)
    M[:2, :2] = [[np.cos(0.4), -np.sin(0.4)], [np.sin(0.4), np.cos(0.4)]]
    M[:3, 3] = [500.0, -300.0, 0.0]  # the map re-anchored after it was made; its .tum still in the old frame
    write_map(tmp_path / "site.pcd", built.points @ M[:3, :3].T + M[:3, 3], built.T_map_sensor, built.stamps_ns)
    cfg = Config().replace(**{"registration.network_process": "off", "node.target_mode": "localization",
                              "node.warmup": False, "localization.map_path": str(tmp_path / "site.pcd")})
    h = Harness(cfg, "first_day_node", registration=DeepBBSRegistration(cfg))
    try:
        for i, k in enumerate((8, 11, 14)):
            h.send("source_cloud", scans[k].points, scans[k].stamp_ns, "lidar")
            h.wait_processed(i + 1, timeout=90.0)
        assert h.wait_for(lambda: len(h.poses) >= h.node.outputs.published, 5.0)
        assert h.poses, h.node.localization.diagnostics()
        for msg in h.poses:  # the scans' poses in the moved map frame
            T, stamp, _ = pose_stamped_to_matrix(msg)
            truth = M @ next(s.T_world_lidar for s in scans if s.stamp_ns == stamp)
            assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.3
        assert "internal_error" not in h.node.stats()["errors"], h.node.stats()
    finally:
        h.close()
    log = capfd.readouterr().err
    assert log.count("the map's trajectory does not fit the map") == 1, log
    assert "a grid over its free space" in log and "internal_error" not in log, log
