"""deepbbs-bag: convert between every format, info output, one-line errors with exit code 1."""

from __future__ import annotations

import json

import numpy as np

from deepbbs_ros.cli.bag import main
from deepbbs_ros.datasets import Scan, open_source, write_scans


def _scans(n: int = 3) -> list[Scan]:
    rng = np.random.default_rng(7)
    out = []
    for i in range(n):
        T = np.eye(4)
        T[:3, 3] = [i * 1.5, 0.1 * i, 0.0]
        out.append(
            Scan(i, 10**18 + i * 10**8, rng.normal(size=(200, 3)) * 10,
                 {"intensity": rng.uniform(0, 100, 200).astype(np.float32)}, T_world_lidar=T)
        )
    return out


def test_convert_apollo_to_mcap_to_kitti_to_db3(tmp_path, capsys):
    scans = _scans()
    write_scans(scans, tmp_path / "apollo", "apollo")
    assert main(["convert", str(tmp_path / "apollo"), str(tmp_path / "bag")]) == 0
    assert "wrote 3 frames with ground truth" in capsys.readouterr().out
    assert main(["convert", str(tmp_path / "bag"), str(tmp_path / "kitti"), "--format", "kitti"]) == 0
    args = ["convert", str(tmp_path / "kitti"), str(tmp_path / "db3"), "--format", "db3", "--max-frames", "2"]
    assert main(args) == 0
    back = list(open_source(tmp_path / "db3"))
    assert len(back) == 2
    for a, b in zip(scans, back):
        np.testing.assert_array_equal(b.points, a.points)
        np.testing.assert_array_equal(b.fields["intensity"], a.fields["intensity"])
        np.testing.assert_allclose(b.T_world_lidar, a.T_world_lidar, atol=1e-9)


def test_info_lists_topics_counts_duration_and_ground_truth(tmp_path, capsys):
    write_scans(_scans(), tmp_path / "bag", "mcap")
    assert main(["info", str(tmp_path / "bag"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "rosbag2-mcap" and info["frames"] == 3 and info["ground_truth"] is True
    assert info["duration_s"] == 0.2
    assert {t["topic"]: (t["type"], t["count"]) for t in info["topics"]} == {
        "/apollo/sensor/velodyne64/compensator/PointCloud2": ("sensor_msgs/msg/PointCloud2", 3),
        "/ground_truth/pose": ("geometry_msgs/msg/PoseStamped", 3),
    }
    assert main(["info", str(tmp_path / "bag")]) == 0
    text = capsys.readouterr().out
    assert "sensor_msgs/msg/PointCloud2" in text and "ground truth" in text and "yes" in text


def test_errors_are_one_line_and_exit_1(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nothing.mcap")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("deepbbs-bag: error: ") and "no such file or directory" in err and "\n" not in err
    write_scans(_scans(1), tmp_path / "a", "apollo")
    write_scans(_scans(1), tmp_path / "b", "apollo")
    assert main(["convert", str(tmp_path / "a"), str(tmp_path / "b")]) == 1
    assert "exists already, not overwriting" in capsys.readouterr().err
