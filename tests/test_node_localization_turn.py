"""The live node on a sensor that turns back, over real DDS: every scan after the first pose is placed right by GICP
(from the last pose at rest, the start the scan fits better: core/guess_tracking.py), none by the DeepBBS++ path
(several scan periods at 10 Hz, during which the scans that arrive are dropped). The scans are sent one at a time
(each answered before the next: the test does not depend on the machine's speed); the map and the drive are
tests/test_node_localization.py's, every second frame (2.3 m a scan at 10 Hz), forwards and back."""

from __future__ import annotations

import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
import test_node_localization  # noqa: E402
from test_node import Harness, _check_pose  # noqa: E402
from test_node_localization import _config, _registration, _write_map  # noqa: E402

from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context
drive = test_node_localization.drive  # the module fixture: the simulated drive and its map


def test_turn_back_tracked_by_gicp(ros, drive, tmp_path):
    sim, points, poses, scan = drive
    _write_map(tmp_path / "map.pcd", points, poses)
    cfg = _config(**{"localization.map_path": str(tmp_path / "map.pcd"), "node.localization_odom": "none",
                     "node.base_frame": ""})
    h = Harness(cfg, "turn_node", registration=_registration(cfg))
    try:
        frames = [76, 78, 80, 82, 84, 82, 80, 78, 76]  # turns back at 84: the prediction there is 4.7 m off
        stamps = [sim.stamp_ns(76) + i * 100_000_000 for i in range(len(frames))]
        for i, (k, stamp) in enumerate(zip(frames, stamps)):
            h.send("source_cloud", scan(k)[0], stamp, "lidar")
            h.wait_processed(i + 1, timeout=90.0)
            if i == 0:
                assert h.node.localization.state == "tracking", h.node.localization.diagnostics()
                paths = dict(h.node._paths)  # the search's answer
        assert h.wait_for(lambda: len(h.poses) >= len(frames), 10.0), len(h.poses)
        got = {pose_stamped_to_matrix(m)[1]: pose_stamped_to_matrix(m)[0] for m in h.poses}
        assert sorted(got) == stamps
        for k, stamp in zip(frames, stamps):
            _check_pose(got[stamp], scan(k)[1])
        after = {p: n - paths[p] for p, n in h.node._paths.items()}
        assert after == {"gicp": len(frames) - 1, "deepbbs": 0, "search": 0}, after
        d = h.node.localization.diagnostics()
        assert d["state"] == "tracking" and d["rejected"] == 0 and d["recoveries"] == 0, d
    finally:
        h.close()
