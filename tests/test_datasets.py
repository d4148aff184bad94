"""Readers and writers: round trips through every format, ROS 1 bags, bare mcap, topic choice,
ground-truth matching, bad input (strict and lenient) and deterministic writing.

Bags are real ones written by rosbags into tmp_path; PointCloud2 and pose messages are built by
msg_adapters, as the package's writers do.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepbbs_ros.datasets import (
    APOLLO_LIDAR_TOPIC,
    GT_POSE_TOPIC,
    PoseTrack,
    Scan,
    open_source,
    write_pcd,
    write_scans,
)
from deepbbs_ros.datasets.kitti import KITTI_TR
from deepbbs_ros.errors import BagError, DatasetError

T0_NS = 1_700_000_000_000_000_000  # a realistic epoch stamp: exactness of ns stamps matters here
DT_NS = 100_000_000  # 10 Hz


def random_pose(rng: np.random.Generator) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * 0.4).as_matrix()
    T[:3, 3] = rng.normal(size=3) * 20
    return T


def make_scans(n: int = 4, npts: int = 400, seed: int = 0, gt: bool = True) -> list[Scan]:
    rng = np.random.default_rng(seed)
    scans = []
    for i in range(n):
        m = npts + i  # different sizes per frame
        fields = {
            "intensity": rng.uniform(0, 255, m).astype(np.float32),
            "time": np.linspace(0, 0.1, m, dtype=np.float32),
            "ring": rng.integers(0, 64, m).astype(np.uint16),
        }
        T = random_pose(rng) if gt else None
        scans.append(Scan(i, T0_NS + i * DT_NS, rng.normal(size=(m, 3)) * 25, fields, T_world_lidar=T))
    return scans


def write_bag(path: Path, messages: list[tuple[str, str, int, object]], storage: str = "mcap") -> None:
    """A rosbag2 with arbitrary (topic, msgtype, log_time_ns, rosbags message) entries."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for topic, typ, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, typ, typestore=ts)
            writer.write(conns[topic], t, ts.serialize_cdr(msg, typ))


def cloud_msg(scan: Scan):
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2

    return arrays_to_pointcloud2(
        scan.points, scan.fields, stamp_ns=scan.stamp_ns, frame_id=scan.frame_id, flavor="rosbags"
    )


PC2 = "sensor_msgs/msg/PointCloud2"


# ----------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("fmt", ["apollo", "kitti", "mcap", "db3", "bag"])
def test_round_trip_every_format(tmp_path, fmt):
    scans = make_scans()
    out = tmp_path / ("drive.bag" if fmt == "bag" else fmt)
    assert write_scans(scans, out, fmt) == len(scans)
    source = open_source(out)
    assert len(source) == len(scans) and source.has_ground_truth
    back = list(source)
    assert len(back) == len(scans) and source.errors == []
    for a, b in zip(scans, back):
        np.testing.assert_array_equal(b.points, a.points)
        np.testing.assert_array_equal(b.fields["intensity"], a.fields["intensity"])
        np.testing.assert_allclose(b.T_world_lidar, a.T_world_lidar, rtol=0, atol=1e-9)
        if fmt == "kitti":  # KITTI keeps times relative to the first scan
            assert b.stamp_ns == a.stamp_ns - T0_NS
        else:
            assert b.stamp_ns == a.stamp_ns
        if fmt in ("mcap", "db3", "bag"):  # bags keep every field with its dtype
            assert b.fields["ring"].dtype == np.uint16
            np.testing.assert_array_equal(b.fields["ring"], a.fields["ring"])
            np.testing.assert_array_equal(b.fields["time"], a.fields["time"])
            assert b.frame_id == "velodyne64"
    assert [s.index for s in back] == ([1, 2, 3, 4] if fmt == "apollo" else [0, 1, 2, 3])


def test_ros1_bag_writer_refuses_other_names_and_layouts(tmp_path):
    with pytest.raises(BagError, match=r"\*\.bag"):
        write_scans(make_scans(1), tmp_path / "drive", "bag")
    with pytest.raises(DatasetError, match="rosbag2 only"):
        write_scans(make_scans(1), tmp_path / "drive.bag", "bag", driver="velodyne")
    write_scans(make_scans(1), tmp_path / "drive.bag", "bag")
    with pytest.raises(BagError, match="exists already"):
        write_scans(make_scans(1), tmp_path / "drive.bag", "bag")


def test_mcap_bag_layout_compression_and_qos(tmp_path):
    import yaml
    from mcap.reader import make_reader

    write_scans(make_scans(), tmp_path / "bag", "mcap")
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert set(topics) == {APOLLO_LIDAR_TOPIC, GT_POSE_TOPIC}
    for t in topics.values():
        assert t["message_count"] == 4
        (qos,) = t["topic_metadata"]["offered_qos_profiles"]
        assert qos["reliability"] == "reliable" and qos["durability"] == "volatile" and qos["depth"] == 10
    with open(tmp_path / "bag" / "bag.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}


def test_gt_pose_message_frames(tmp_path):
    from rosbags.highlevel import AnyReader

    scans = make_scans(2)
    write_scans(scans, tmp_path / "bag", "mcap")
    with AnyReader([tmp_path / "bag"]) as reader:
        conns = [c for c in reader.connections if c.topic == GT_POSE_TOPIC]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert [m.header.frame_id for m in msgs] == ["world", "world"]
    assert msgs[1].header.stamp.sec * 10**9 + msgs[1].header.stamp.nanosec == scans[1].stamp_ns
    assert msgs[1].pose.position.x == pytest.approx(scans[1].T_world_lidar[0, 3])


def test_writing_is_deterministic(tmp_path):
    for fmt in ("mcap", "db3", "apollo", "kitti"):
        a, b = tmp_path / "a" / fmt, tmp_path / "b" / fmt  # same names: a bag's file is named after its folder
        write_scans(make_scans(seed=3), a, fmt)
        write_scans(make_scans(seed=3), b, fmt)
        files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
        assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
        for rel in files:
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), f"{fmt}: {rel}"


def test_bare_mcap_and_db3_files(tmp_path):
    scans = make_scans(3)
    write_scans(scans, tmp_path / "m", "mcap")
    write_scans(scans, tmp_path / "d", "db3")
    shutil.copy(tmp_path / "m" / "m.mcap", tmp_path / "bare.mcap")
    shutil.copy(tmp_path / "d" / "d.db3", tmp_path / "bare.db3")
    for name in ("bare.mcap", "bare.db3"):
        source = open_source(tmp_path / name)
        back = list(source)
        assert len(back) == 3 and source.has_ground_truth
        np.testing.assert_array_equal(back[2].points, scans[2].points)
        np.testing.assert_allclose(back[2].T_world_lidar, scans[2].T_world_lidar, atol=1e-12)


def test_ros1_bag(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    PointField, PointCloud2 = ts.types["sensor_msgs/msg/PointField"], ts.types["sensor_msgs/msg/PointCloud2"]
    PoseStamped = ts.types["geometry_msgs/msg/PoseStamped"]
    Pose, Point, Quat = ts.types["geometry_msgs/msg/Pose"], ts.types["geometry_msgs/msg/Point"], ts.types[
        "geometry_msgs/msg/Quaternion"
    ]
    scans = make_scans(3)
    path = tmp_path / "drive.bag"
    with Writer(path) as writer:
        c_cloud = writer.add_connection("/velodyne_points", PointCloud2.__msgtype__, typestore=ts)
        c_gt = writer.add_connection("/ground_truth/odom_pose", PoseStamped.__msgtype__, typestore=ts)
        for i, s in enumerate(scans):
            m2 = cloud_msg(s)  # ROS 2 layout, re-wrapped as a ROS 1 message (Header has seq)
            stamp = Time(sec=s.stamp_ns // 10**9, nanosec=s.stamp_ns % 10**9)
            header = Header(seq=i, stamp=stamp, frame_id="velodyne")
            fields = [PointField(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in m2.fields]
            msg = PointCloud2(header, m2.height, m2.width, fields, m2.is_bigendian, m2.point_step, m2.row_step,
                              m2.data, m2.is_dense)
            writer.write(c_cloud, s.stamp_ns, ts.serialize_ros1(msg, PointCloud2.__msgtype__))
            q = Rotation.from_matrix(s.T_world_lidar[:3, :3]).as_quat()
            x, y, z, qx, qy, qz, qw = [*s.T_world_lidar[:3, 3], *q]
            pose = PoseStamped(Header(seq=i, stamp=stamp, frame_id="world"),
                               Pose(Point(x=x, y=y, z=z), Quat(x=qx, y=qy, z=qz, w=qw)))
            writer.write(c_gt, s.stamp_ns, ts.serialize_ros1(pose, PoseStamped.__msgtype__))
    source = open_source(path)
    assert source.format == "rosbag1" and source.topic == "/velodyne_points"
    assert source.gt_topic == "/ground_truth/odom_pose"  # picked by its name, not given
    back = list(source)
    assert [b.frame_id for b in back] == ["velodyne"] * 3
    for a, b in zip(scans, back):
        np.testing.assert_array_equal(b.points, a.points)
        np.testing.assert_array_equal(b.fields["ring"], a.fields["ring"])
        np.testing.assert_allclose(b.T_world_lidar, a.T_world_lidar, atol=1e-9)
    data = path.read_bytes()  # damaged copies: a clear error, or scans (a ROS 1 bag has no checksum:
    for k, cut in enumerate([0.02, 0.3, 0.6, 0.9, 0.99]):  # zeroed payload bytes can pass; a cut keeps a prefix)
        for how in ("cut", "zero"):
            bad = tmp_path / f"bad_{how}_{k}.bag"
            n = int(cut * len(data))
            bad.write_bytes(data[:n] if how == "cut" else data[:n] + bytes(min(512, len(data) - n)) + data[n + 512:])
            try:
                source = open_source(bad, lenient=True)
                got = list(source)
            except DatasetError as err:
                assert bad.name in str(err)
                continue
            for a, b in zip(scans, got if how == "cut" else []):
                np.testing.assert_array_equal(b.points, a.points)


# ------------------------------------------------------------------------------------ topic choice
def test_topic_auto_pick_and_several_topics_error(tmp_path):
    scans = make_scans(2, gt=False)
    one = [("/points_raw", PC2, s.stamp_ns, cloud_msg(s)) for s in scans]
    write_bag(tmp_path / "one", one)
    source = open_source(tmp_path / "one")
    assert source.topic == "/points_raw" and not source.has_ground_truth
    assert [b.T_world_lidar for b in source] == [None, None]

    two = one + [("/lidar_front/points", PC2, s.stamp_ns + 1, cloud_msg(s)) for s in scans]
    write_bag(tmp_path / "two", two)
    match = r"2 PointCloud2 topics \(/lidar_front/points, /points_raw\); pick one with --topic"
    with pytest.raises(DatasetError, match=match):
        open_source(tmp_path / "two")
    assert open_source(tmp_path / "two", topic="/lidar_front/points").topic == "/lidar_front/points"
    with pytest.raises(BagError, match=r"no topic '/nope'; PointCloud2 topics: /lidar_front/points, /points_raw"):
        open_source(tmp_path / "two", topic="/nope")


def test_wheel_odometry_is_not_taken_as_ground_truth(tmp_path):
    from msg_adapters.transforms import matrix_to_odometry

    scans = make_scans(2)
    msgs = [(APOLLO_LIDAR_TOPIC, PC2, s.stamp_ns, cloud_msg(s)) for s in scans]
    msgs += [("/odom", "nav_msgs/msg/Odometry", s.stamp_ns, matrix_to_odometry(s.T_world_lidar, s.stamp_ns, "odom",
             "velodyne64", flavor="rosbags")) for s in scans]
    write_bag(tmp_path / "bag", msgs)
    assert not open_source(tmp_path / "bag").has_ground_truth
    source = open_source(tmp_path / "bag", gt_topic="/odom")  # asked for explicitly: used
    np.testing.assert_allclose(list(source)[1].T_world_lidar, scans[1].T_world_lidar, atol=1e-9)
    with pytest.raises(BagError, match=r"ground-truth topic '/apollo/.*' is sensor_msgs/msg/PointCloud2"):
        open_source(tmp_path / "bag", gt_topic=APOLLO_LIDAR_TOPIC)


# ---------------------------------------------------------------------------- ground-truth matching
def test_pose_track_matching_rule():
    Ta, Tb = np.eye(4), np.eye(4)
    Tb[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    Tb[:3, 3] = [2.0, 0.0, 0.0]
    track = PoseTrack([1000, 0], [Tb, Ta], tolerance_ns=600)  # unsorted input
    np.testing.assert_array_equal(track.lookup(0), Ta)  # exact
    mid = track.lookup(500)  # both within tolerance: interpolated (SLERP + linear)
    np.testing.assert_allclose(mid[:3, 3], [1.0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(mid[:3, :3]).as_euler("xyz", degrees=True), [0, 0, 45], atol=1e-9)
    np.testing.assert_array_equal(track.lookup(1500), Tb)  # only one side close: nearest
    np.testing.assert_array_equal(track.lookup(300), track.lookup(300))
    assert track.lookup(1700) is None and track.lookup(-700) is None  # beyond tolerance


@pytest.mark.parametrize("gt_type", ["nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped"])
def test_gt_topic_at_100hz_is_interpolated_to_scan_stamps(tmp_path, gt_type):
    from msg_adapters.transforms import matrix_to_odometry, matrix_to_transform_stamped

    scans = make_scans(3, gt=False)
    v = np.array([10.0, -2.0, 0.5])  # m/s, constant velocity, constant yaw rate

    def pose_at(t_ns: int) -> np.ndarray:
        t = (t_ns - T0_NS) * 1e-9
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", 0.3 * t).as_matrix()
        T[:3, 3] = v * t
        return T

    msgs = [(APOLLO_LIDAR_TOPIC, PC2, s.stamp_ns, cloud_msg(s)) for s in scans]
    for k in range(-2, 25):  # 100 Hz, offset 3 ms from the scan stamps
        t = T0_NS + 3_000_000 + k * 10_000_000
        if gt_type.endswith("Odometry"):
            m = matrix_to_odometry(pose_at(t), t, "world", "velodyne64", flavor="rosbags")
        else:
            m = matrix_to_transform_stamped(pose_at(t), t, "world", "velodyne64", flavor="rosbags")
        msgs.append(("/novatel/ground_truth", gt_type, t, m))
    write_bag(tmp_path / "bag", msgs)
    source = open_source(tmp_path / "bag", gt_tolerance_s=0.01)
    assert source.gt_topic == "/novatel/ground_truth"
    for s in source:
        np.testing.assert_allclose(s.T_world_lidar, pose_at(s.stamp_ns), atol=1e-9)


def test_scan_without_ground_truth_strict_and_lenient(tmp_path):
    from msg_adapters.transforms import matrix_to_pose_stamped

    scans = make_scans(4)
    msgs = [(APOLLO_LIDAR_TOPIC, PC2, s.stamp_ns, cloud_msg(s)) for s in scans]
    msgs += [(GT_POSE_TOPIC, "geometry_msgs/msg/PoseStamped", s.stamp_ns,
              matrix_to_pose_stamped(s.T_world_lidar, s.stamp_ns, "world", flavor="rosbags")) for s in scans[:2]]
    write_bag(tmp_path / "bag", msgs, storage="sqlite3")
    match = r"scan 2 \(stamp 1700000000.200000 s\) has no ground truth on /ground_truth/pose"
    with pytest.raises(BagError, match=match):
        list(open_source(tmp_path / "bag"))
    source = open_source(tmp_path / "bag", lenient=True)
    assert [s.index for s in source] == [0, 1]
    assert len(source.errors) == 1 and "scan 2" in source.errors[0]


# -------------------------------------------------------------------------------------- bad input
def test_truncated_mcap_strict_and_lenient(tmp_path):
    scans = make_scans(6, npts=30_000)  # ~1 MiB chunks: the cut leaves whole chunks before it
    write_scans(scans, tmp_path / "bag", "mcap")
    f = tmp_path / "bag" / "bag.mcap"
    data = f.read_bytes()
    f.write_bytes(data[: int(len(data) * 0.75)])
    with pytest.raises(BagError, match=r"bag\.mcap: bag is truncated or corrupt"):
        list(open_source(tmp_path / "bag"))
    source = open_source(tmp_path / "bag", lenient=True)
    back = list(source)
    assert 1 <= len(back) < 6 and "truncated" in source.errors[0]
    for a, b in zip(scans, back):
        np.testing.assert_array_equal(b.points, a.points)
        np.testing.assert_allclose(b.T_world_lidar, a.T_world_lidar, atol=1e-9)


def test_garbage_bag_is_one_clear_error(tmp_path):
    (tmp_path / "x.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    with pytest.raises(BagError, match=r"x\.bag: cannot read bag"):
        open_source(tmp_path / "x.bag")
    with pytest.raises(DatasetError, match="no such file or directory"):
        open_source(tmp_path / "missing.mcap")


def test_apollo_malformed_pose_line_and_missing_pose(tmp_path):
    scans = make_scans(4, npts=50)
    write_scans(scans, tmp_path / "s", "apollo")
    pose_file = tmp_path / "s" / "poses" / "gt_poses.txt"
    lines = pose_file.read_text().splitlines()
    pose_file.write_text("\n".join([*lines[:2], "3 1700000000.2 1.0 2.0 oops 0 0 0 1", lines[3]]) + "\n")
    with pytest.raises(DatasetError, match=r"gt_poses\.txt: line 3: malformed pose line: could not convert"):
        open_source(tmp_path / "s")
    source = open_source(tmp_path / "s", lenient=True)
    assert [s.index for s in source] == [1, 2]  # frame 3 has no pose: stop there
    assert len(source.errors) == 1 and "line 3" in source.errors[0]

    pose_file.write_text("\n".join(lines[:2] + lines[3:]) + "\n")  # frame 3 simply missing
    with pytest.raises(DatasetError, match=r"frame 3 \(3\.pcd\) has no ground-truth pose"):
        list(open_source(tmp_path / "s"))


def test_apollo_bad_pcd_header_and_nan_points(tmp_path):
    scans = make_scans(3, npts=50)
    write_scans(scans, tmp_path / "s", "apollo")
    pts = scans[0].points.copy()
    pts[[0, 5]] = np.nan
    intensity = np.arange(len(pts), dtype=np.float32)
    write_pcd(tmp_path / "s" / "pcds" / "1.pcd", {"points": pts, "intensity": intensity}, "binary_compressed")
    first = next(iter(open_source(tmp_path / "s")))
    assert len(first) == len(pts) - 2 and np.isfinite(first.points).all()
    np.testing.assert_array_equal(first.fields["intensity"], np.delete(intensity, [0, 5]))

    bad = tmp_path / "s" / "pcds" / "3.pcd"
    bad.write_bytes(bad.read_bytes().replace(b"SIZE 4 4 4 4", b"SIZE 4 4 4"))
    with pytest.raises(DatasetError, match=r"3\.pcd: line 4: bad PCD header: SIZE has 3 entries"):
        list(open_source(tmp_path / "s"))
    source = open_source(tmp_path / "s", lenient=True)
    assert [s.index for s in source] == [1, 2] and "3.pcd" in source.errors[0]


def test_kitti_poses_are_converted_to_the_lidar_frame(tmp_path):
    """poses.txt holds camera poses; T_world_lidar = Tr^-1 @ P @ Tr (world = LiDAR frame of frame 0)."""
    seq = tmp_path / "00"
    (seq / "velodyne").mkdir(parents=True)
    rng = np.random.default_rng(5)
    P = [np.eye(4), random_pose(rng)]
    for i in range(2):
        rec = np.hstack([rng.normal(size=(10, 3)), rng.random((10, 1))]).astype("<f4")
        (seq / "velodyne" / f"{i:06d}.bin").write_bytes(rec.tobytes())
    (seq / "poses.txt").write_text("".join(" ".join(f"{v:.15e}" for v in p[:3].ravel()) + "\n" for p in P))
    (seq / "calib.txt").write_text("Tr: " + " ".join(f"{v:.12e}" for v in KITTI_TR[:3].ravel()) + "\n")
    back = list(open_source(seq))
    np.testing.assert_allclose(back[0].T_world_lidar, np.eye(4), atol=1e-12)
    # a LiDAR point of frame 1 mapped to the world equals the same point through the camera chain
    p_lidar = np.array([3.0, -1.0, 0.5, 1.0])
    p_world_via_cam = np.linalg.inv(KITTI_TR) @ P[1] @ KITTI_TR @ p_lidar
    np.testing.assert_allclose(back[1].T_world_lidar @ p_lidar, p_world_via_cam, atol=1e-9)
    assert [b.stamp_ns for b in back] == [0, DT_NS]  # no times.txt: 10 Hz

    (seq / "poses.txt").write_text("1 2 3\n")
    with pytest.raises(DatasetError, match=r"poses\.txt: line 1: malformed pose line: 3 values, expected 12"):
        open_source(seq)
    (seq / "calib.txt").write_text("P0: 1 2 3\n")
    with pytest.raises(DatasetError, match=r"calib\.txt: no 'Tr:' line"):
        open_source(seq)


def test_writer_errors(tmp_path):
    with pytest.raises(DatasetError, match="unknown output format 'las'"):
        write_scans(make_scans(1), tmp_path / "x", "las")
    write_scans(make_scans(1), tmp_path / "a", "apollo")
    with pytest.raises(DatasetError, match="exists already, not overwriting"):
        write_scans(make_scans(1), tmp_path / "a", "apollo")
    write_scans(make_scans(1), tmp_path / "b", "mcap")
    with pytest.raises(BagError, match="exists already"):
        write_scans(make_scans(1), tmp_path / "b", "mcap")
    mixed = make_scans(2)
    mixed[1].T_world_lidar = None
    with pytest.raises(DatasetError, match="scan 1 lacks ground truth"):
        write_scans(mixed, tmp_path / "k", "kitti")


@pytest.mark.parametrize("driver", ["velodyne", "ouster"])
def test_rosbag_in_a_driver_layout_reads_back(tmp_path, driver):
    """Raw sweeps written in a real driver's PointCloud2 layout (Velodyne PointXYZIRT, organised ouster-ros
    PointOS with zeros for no return) read back as the same points with per-point times in seconds."""
    from deepbbs_ros.datasets import open_source, write_scans
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    lid = (LidarConfig.ouster64(beams=16, azimuth_step_deg=2.0) if driver == "ouster"
           else LidarConfig.hdl64(azimuth_step_deg=2.0))
    scans = list(simulate_drive("suburban", 3, 2, lidar=lid))
    out = tmp_path / driver
    write_scans(scans, out, "mcap", topic="/points", driver=driver, shape=(lid.beams, lid.columns))
    back = list(open_source(out))
    assert len(back) == 2
    for a, b in zip(scans, back):
        order_a = np.lexsort(a.points.T)
        order_b = np.lexsort(b.points.T)
        np.testing.assert_array_equal(a.points[order_a], b.points[order_b])
        np.testing.assert_allclose(a.fields["time"][order_a], b.point_times()[order_b], atol=1e-9)
        np.testing.assert_allclose(a.T_world_lidar, b.T_world_lidar, atol=1e-9)
