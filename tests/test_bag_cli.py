"""deepbbs-bag: convert between every format, info output, one-line errors with exit code 1."""

from __future__ import annotations

import json

import numpy as np
import pytest

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


def test_convert_to_a_ros1_bag_and_back(tmp_path, capsys):
    scans = _scans()
    write_scans(scans, tmp_path / "apollo", "apollo")
    assert main(["convert", str(tmp_path / "apollo"), str(tmp_path / "drive.bag"), "--format", "bag"]) == 0
    assert "wrote 3 frames with ground truth" in capsys.readouterr().out
    back = list(open_source(tmp_path / "drive.bag"))
    assert len(back) == 3
    for a, b in zip(scans, back):
        np.testing.assert_array_equal(b.points, a.points)
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


def test_convert_keeps_topic_and_organised_layout_unless_repacked(tmp_path, capsys):
    """An organised ouster-ros cloud: convert copies it as recorded (topic, 16 x 90 layout, fields, bytes);
    --repack writes x y z + fields, unorganised; --out-topic renames."""
    from rosbags.highlevel import AnyReader

    from deepbbs_ros.sim import LidarConfig, simulate_drive

    lid = LidarConfig.ouster64(beams=16, azimuth_step_deg=4.0)
    scans = list(simulate_drive("suburban", 3, 2, lidar=lid))
    write_scans(scans, tmp_path / "os", "mcap", topic="/ouster/points", driver="ouster", shape=(lid.beams, lid.columns))
    assert main(["convert", str(tmp_path / "os"), str(tmp_path / "copy")]) == 0
    assert "/ouster/points, copied as recorded" in capsys.readouterr().out
    assert main(["convert", str(tmp_path / "os"), str(tmp_path / "flat"), "--repack"]) == 0
    assert main(["convert", str(tmp_path / "os"), str(tmp_path / "renamed"), "--out-topic", "/lidar"]) == 0

    def clouds(path):
        with AnyReader([path]) as r:
            return [(c.topic, r.deserialize(raw, c.msgtype), raw) for c, _t, raw in r.messages()
                    if c.msgtype == "sensor_msgs/msg/PointCloud2"]

    src, copy, flat, renamed = (clouds(tmp_path / n) for n in ("os", "copy", "flat", "renamed"))
    assert [m.height for _t, m, _r in src] == [16, 16] and [m.width for _t, m, _r in src] == [90, 90]
    assert [(t, bytes(r)) for t, _m, r in copy] == [(t, bytes(r)) for t, _m, r in src]
    assert {t for t, _m, _r in renamed} == {"/lidar"}
    assert [bytes(r) for _t, _m, r in renamed] == [bytes(r) for _t, _m, r in src]
    assert {t for t, _m, _r in flat} == {"/ouster/points"} and {m.height for _t, m, _r in flat} == {1}
    for a, b in zip(open_source(tmp_path / "os"), open_source(tmp_path / "flat")):
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_allclose(a.T_world_lidar, b.T_world_lidar, atol=1e-12)


def test_info_lists_every_pointcloud2_topic(tmp_path, capsys):
    from rosbags.typesys import Stores, get_typestore

    from deepbbs_ros.datasets.rosbag import rosbag2_writer
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    ts = get_typestore(Stores.ROS2_JAZZY)
    pc2 = "sensor_msgs/msg/PointCloud2"
    with rosbag2_writer(tmp_path / "two") as w:
        conns = {t: w.add_connection(t, pc2, typestore=ts) for t in ("/front/points", "/rear/points")}
        for k in range(3):
            for t, c in conns.items():
                msg = arrays_to_pointcloud2(np.ones((5, 3), np.float32) * k, stamp_ns=k, frame_id=t[1:5],
                                            flavor="rosbags")
                w.write(c, k, ts.serialize_cdr(msg, pc2))
    assert main(["info", str(tmp_path / "two"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["cloud_topics"] == ["/front/points", "/rear/points"] and info["topic"] is None
    assert {t["topic"]: t["count"] for t in info["topics"]} == {"/front/points": 3, "/rear/points": 3}
    assert main(["info", str(tmp_path / "two")]) == 0
    text = capsys.readouterr().out
    assert "/front/points, /rear/points" in text and "--topic" in text
    assert main(["info", str(tmp_path / "two"), "--topic", "/rear/points", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 3
    assert main(["convert", str(tmp_path / "two"), str(tmp_path / "out")]) == 1  # convert needs one: says so
    assert "pick one with --topic" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".bin", ".pcd"])
def test_plain_folder_of_scans_reads_in_name_order(tmp_path, suffix, capsys):
    from deepbbs_ros.datasets import write_pcd

    scans = _scans()
    folder = tmp_path / "scans"
    folder.mkdir()
    names = ["scan_2", "scan_10", "scan_1"]  # name order with digits as numbers: 1, 2, 10
    for name, scan in zip(names, scans):
        if suffix == ".bin":
            rec = np.concatenate([scan.points, scan.fields["intensity"][:, None]], axis=1).astype("<f4")
            (folder / f"{name}.bin").write_bytes(rec.tobytes())
        else:
            write_pcd(folder / f"{name}.pcd", {"points": scan.points, "intensity": scan.fields["intensity"]})
    (folder / "notes.txt").write_text("not a scan\n")
    source = open_source(folder)
    assert source.format == "folder" and not source.has_ground_truth and len(source) == 3
    back = list(source)
    order = [2, 0, 1]  # scan_1, scan_2, scan_10
    assert [s.stamp_ns for s in back] == [0, 100_000_000, 200_000_000]
    for b, k in zip(back, order):
        np.testing.assert_array_equal(b.points, scans[k].points)
        np.testing.assert_array_equal(b.fields["intensity"], scans[k].fields["intensity"])
        assert b.T_world_lidar is None
    assert main(["info", str(folder), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == 3 and info["ground_truth"] is False
