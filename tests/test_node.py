"""The live node with real rclpy and DDS: conventions, bad input, odometry mode, start-up errors.

The node runs in-process on a MultiThreadedExecutor next to a test client node; clouds travel over
real DDS (loopback, per-run domain, shipped shared-memory profile). Registration is the real
DeepBBSRegistration; these tests check the node, so they use a tiny random network with the
refinement only (``registration.deep: false``, a real configuration) on small motions, which does not
depend on trained weights. Accuracy with the shipped weights is tested in test_play.py.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseStamped, TransformStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.errors import NodeError  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from deepbbs_ros.node.covariance import twist_from_delta  # noqa: E402
from deepbbs_ros.node.registration_node import RegistrationNode  # noqa: E402
from deepbbs_ros.replay.synthetic import MOUNT_HEIGHT, pose, scan_at, structured_world  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import (  # noqa: E402
    odometry_covariances,
    odometry_to_matrix,
    odometry_twist,
    pose_stamped_to_matrix,
    transform_stamped_to_matrix,
)

SEC = 1_000_000_000
REPO = Path(__file__).resolve().parents[1]
N_POINTS = 30_000  # enough structure for the refinement; keeps the tests fast on 2 cores

TINY = {
    "model.k": 8,
    "model.dgcnn_widths": [16, 32],
    "model.emb_dims": 32,
    "model.n_heads": 2,
    "model.ff_dims": 64,
    "preprocess.num_points": 512,
    "registration.deep": False,
    "registration.refine": True,
    "registration.polish": "none",
    "registration.device": "cpu",
}


def tiny_config(**extra) -> Config:
    return Config().replace(**{**TINY, **extra})


def tiny_registration(cfg: Config):
    import torch

    registration = pytest.importorskip("deepbbs_ros.core.registration", reason="core registration not available")
    from deepbbs_ros.core.model import DeepBBSNet

    torch.manual_seed(0)
    return registration.DeepBBSRegistration(cfg, model=DeepBBSNet(cfg.model).eval(), device="cpu")


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.fixture(scope="module")
def world():
    """The structured street (deepbbs_ros.replay.synthetic): road along x, façades, boxes, poles."""
    return structured_world(3, length=120.0)


def at(x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """T_world_lidar of a sensor MOUNT_HEIGHT above the road at (x, y), heading ``yaw`` rad."""
    return pose(x, y, MOUNT_HEIGHT, yaw)


def scan(world: np.ndarray, T_world_lidar: np.ndarray, seed: int, n_points: int = N_POINTS) -> np.ndarray:
    return scan_at(world, T_world_lidar, np.random.default_rng(seed), n_points=n_points)


def wait_for(cond, timeout: float = 30.0) -> bool:
    """Poll ``cond()`` every 20 ms until it holds (True) or ``timeout`` s pass (False)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return False


class Harness:
    """The node plus a client node (publishers of the inputs, subscribers of the outputs); ``node_kwargs``
    go to RegistrationNode (e.g. ``odometry_method``)."""

    def __init__(self, cfg: Config, name: str, registration=None, **node_kwargs) -> None:
        registration = registration or tiny_registration(cfg)
        self.node = RegistrationNode(cfg, registration=registration, node_name=name, **node_kwargs)
        self.client = rclpy.create_node(f"{name}_client")
        self.poses: list[PoseStamped] = []
        self.transforms: list[TransformStamped] = []
        self.odoms: list[Odometry] = []
        self.diags: list[DiagnosticArray] = []
        c = self.client
        c.create_subscription(PoseStamped, f"/{name}/pose", self.poses.append, 50)
        c.create_subscription(TransformStamped, f"/{name}/transform", self.transforms.append, 50)
        c.create_subscription(Odometry, f"/{name}/odometry", self.odoms.append, 50)
        c.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 50)
        self.pub = {t: c.create_publisher(PointCloud2, t, 5) for t in ("source_cloud", "target_cloud", "cloud")}
        self.reset = c.create_client(Trigger, f"/{name}/reset")
        self.executor = MultiThreadedExecutor(num_threads=3)
        self.executor.add_node(self.node)
        self.executor.add_node(c)
        self.spin_error = ""  # the traceback that ended the executor's spin thread, if one did
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        topics = ("source_cloud", "cloud") if cfg.node.mode == "pair" else ("cloud",)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if any(self.pub[t].get_subscription_count() > 0 for t in topics) and c.count_publishers(f"/{name}/pose"):
                break
            time.sleep(0.05)

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except BaseException:
            self.spin_error = traceback.format_exc()
            raise

    def _on_diag(self, msg: DiagnosticArray) -> None:
        if msg.status and msg.status[0].name.startswith(self.node.get_name() + ":"):
            self.diags.append(msg)

    def diagnostics(self) -> dict[str, str]:
        """The key/values of this node's latest /diagnostics message ({} before the first)."""
        return {kv.key: kv.value for kv in self.diags[-1].status[0].values} if self.diags else {}

    def send(self, topic: str, xyz: np.ndarray, stamp_ns: int, frame: str = "lidar") -> None:
        self.pub[topic].publish(arrays_to_pointcloud2(xyz, stamp_ns=stamp_ns, frame_id=frame))

    def send_raw(self, topic: str, msg: PointCloud2) -> None:
        self.pub[topic].publish(msg)

    def wait_for(self, cond, timeout: float = 30.0) -> bool:
        """``wait_for``; a spin thread that died says so (nothing more can arrive), with its traceback."""
        ok = wait_for(cond, timeout)
        assert ok or not self.spin_error, f"the executor's spin thread died:\n{self.spin_error}"
        return ok

    def wait_processed(self, n: int, timeout: float = 30.0) -> None:
        s = self.node.stats
        done = self.wait_for(lambda: s()["processed"] + s()["rejected"] >= n and not self.node.worker.busy, timeout)
        assert done, f"{s()}\n{node_threads()}"

    def close(self) -> None:
        self.executor.shutdown()
        self.thread.join(10.0)  # the spin thread out of its wait set before the nodes' handles go
        self.node.destroy_node()
        self.client.destroy_node()


def node_threads() -> str:
    """Where each of the node's own threads (``deepbbs-*``) is now: the innermost frames of its stack, for the
    message of a test that timed out waiting for the node."""
    names = {t.ident: t.name for t in threading.enumerate()}
    out = []
    for ident, frame in sys._current_frames().items():
        name = names.get(ident, "")
        if name.startswith("deepbbs"):
            out.append(f"thread {name}:\n" + "".join(traceback.format_stack(frame)[-8:]))
    return "\n".join(out) or "no deepbbs thread"


def _check_pose(T_est: np.ndarray, T_gt: np.ndarray, rot_deg: float = 1.0, trans_m: float = 0.3) -> None:
    r, t = pair_errors(T_est, T_gt)
    assert r <= rot_deg and t <= trans_m, f"rot {r:.3f} deg, trans {t:.3f} m\n{T_est}\nvs\n{T_gt}"


def test_pair_mode_publishes_T_target_source(ros, world):
    h = Harness(tiny_config(**{"node.publish_odometry": True}), "reg_pair")
    try:
        T_w_tgt = at(10.0, 2.0, 0.1)
        T_w_src = T_w_tgt @ pose(1.0, 0.2, 0.0, np.deg2rad(3.0))
        tgt_xyz = scan(world, T_w_tgt, seed=1)
        src_xyz = scan(world, T_w_src, seed=2)
        h.send("target_cloud", tgt_xyz, 5 * SEC + 20_000_000, "lidar_t")
        h.send("source_cloud", src_xyz, 5 * SEC, "lidar_s")
        assert h.wait_for(lambda: h.poses and h.transforms and h.odoms), h.node.stats()
        T, stamp, frame = pose_stamped_to_matrix(h.poses[0])
        assert frame == "lidar_t"  # the target cloud's frame
        assert stamp == 5 * SEC  # the source stamp, never the wall clock
        _check_pose(T, np.linalg.inv(T_w_tgt) @ T_w_src)
        T2, stamp2, frame2, child = transform_stamped_to_matrix(h.transforms[0])
        assert (stamp2, frame2, child) == (5 * SEC, "lidar_t", "lidar_s")
        np.testing.assert_allclose(T2, T, atol=1e-6)
        To, _, f_o, c_o = odometry_to_matrix(h.odoms[0])
        np.testing.assert_allclose(To, T, atol=1e-6)
        cov = np.asarray(h.odoms[0].pose.covariance).reshape(6, 6)
        assert (f_o, c_o) == ("lidar_t", "lidar_s")
        assert np.all(np.diag(cov) > 0) and np.allclose(cov, cov.T)
        assert np.all(np.linalg.eigvalsh(cov) > -1e-12)
        s = h.node.stats()
        assert s["processed"] == 1 and s["dropped"] == 0 and s["errors"] == {}
        assert {"decode", "preprocess", "register", "publish", "total"} <= set(s["latency_ms"])
    finally:
        h.close()


def test_pair_mode_withholds_a_pose_the_verdict_rejects(ros, world):
    """A source with nothing in common with the target (points scattered in free space) gets a pose the verdict
    rejects: nothing on ~/pose, counted in the stats and /diagnostics, logged once; the next true pair is published."""
    h = Harness(tiny_config(), "reg_verdict")
    try:
        T_w_tgt = at(10.0, 2.0, 0.1)
        tgt_xyz = scan(world, T_w_tgt, seed=1)
        rng = np.random.default_rng(5)
        d = rng.normal(size=(N_POINTS, 3))
        noise = (d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(5, 60, (N_POINTS, 1))).astype(np.float32)
        h.send("target_cloud", tgt_xyz, 5 * SEC, "lidar_t")
        h.send("source_cloud", noise, 5 * SEC, "lidar_s")
        h.wait_processed(1)
        assert h.wait_for(lambda: h.diagnostics().get("poses not published (the verdict rejected them)") == "1")
        s = h.node.stats()
        assert not h.poses and s["untrusted"] == 1 and s["errors"] == {"untrusted_pose": 1}
        assert s["verdict_probability"] < h.node.cfg.registration.verdict_probability
        src_xyz = scan(world, T_w_tgt @ pose(1.0, 0.2, 0.0, np.deg2rad(3.0)), seed=2)
        h.send("target_cloud", tgt_xyz, 6 * SEC, "lidar_t")
        h.send("source_cloud", src_xyz, 6 * SEC, "lidar_s")
        assert h.wait_for(lambda: h.poses), h.node.stats()
        assert h.node.stats()["untrusted"] == 1
    finally:
        h.close()


def test_pair_mode_starts_from_the_last_answer_and_counts_paths(ros, world):
    """Consecutive scans in pair mode (scan k on source_cloud, scan k-1 on target_cloud): the first pair has no good
    start (the full pipeline: path deepbbs), the next ones start from the last answer and GICP answers (path gicp),
    counted on /diagnostics; after ~/reset the next pair runs the full pipeline again."""
    cfg = tiny_config(**{"registration.polish": "gicp", "node.diagnostics_period": 0.2})
    h = Harness(cfg, "reg_good_start")
    try:
        poses = [at(10.0 + 1.2 * k, 2.0, 0.1 + 0.01 * k) for k in range(5)]
        scans = [scan(world, P, seed=10 + k) for k, P in enumerate(poses)]

        def pair(k: int) -> None:
            stamp = 5 * SEC + k * 100_000_000
            h.send("target_cloud", scans[k - 1], stamp, "lidar")
            h.send("source_cloud", scans[k], stamp, "lidar")
            n = len(h.poses)
            assert h.wait_for(lambda: len(h.poses) > n), h.node.stats()
            T, _, _ = pose_stamped_to_matrix(h.poses[-1])
            _check_pose(T, np.linalg.inv(poses[k - 1]) @ poses[k])

        for k in (1, 2, 3):
            pair(k)
        assert h.wait_for(lambda: h.diagnostics().get("paths.gicp") == "2"), h.diagnostics()
        d = h.diagnostics()
        assert (d["paths.deepbbs"], d["paths.search"]) == ("1", "0"), d
        assert h.reset.wait_for_service(timeout_sec=5.0)
        fut = h.reset.call_async(Trigger.Request())
        assert h.wait_for(fut.done, 10.0) and fut.result().success
        pair(4)  # ~/reset forgot the start: the full pipeline
        assert h.wait_for(lambda: h.diagnostics().get("paths.deepbbs") == "2"), h.diagnostics()
        assert h.node.stats()["paths"] == {"gicp": 2, "deepbbs": 2, "search": 0}
    finally:
        h.close()


def _raw(width: int, height: int, fields, point_step: int, data: bytes, frame: str = "lidar", stamp_s: int = 1):
    m = PointCloud2()
    m.header.frame_id = frame
    m.header.stamp.sec = stamp_s
    m.width, m.height = width, height
    m.fields = [PointField(name=n, offset=o, datatype=d, count=c) for n, o, d, c in fields]
    m.point_step = point_step
    m.row_step = point_step * width
    m.data = data
    return m


XYZ = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)]


def test_bad_input_rejected_then_recovers(ros, world):
    cfg = tiny_config(**{"node.error_log_period": 60.0})
    h = Harness(cfg, "reg_bad")
    try:
        good_t = scan(world, at(), seed=4)
        good_s = scan(world, at(0.8, 0.0, np.deg2rad(2.0)), seed=5)
        nan = np.full((500, 3), np.nan, dtype=np.float32)
        pts = np.ones((200, 3), np.float32)
        cases = [  # (kind, source message)
            ("malformed_cloud", _raw(10, 1, XYZ[:2], 12, bytes(120))),  # no z field
            ("malformed_cloud", _raw(10, 1, XYZ, 12, bytes(119))),  # data length != row_step*height
            ("malformed_cloud", _raw(10, 1, [*XYZ[:2], ("z", 8, 9, 1)], 12, bytes(120))),  # unknown datatype
            ("malformed_cloud", _raw(10, 1, XYZ, 8, bytes(80))),  # z runs past point_step
            ("empty_cloud", _raw(0, 0, XYZ, 12, b"")),
            ("no_valid_points", arrays_to_pointcloud2(nan, stamp_ns=1 * SEC, frame_id="lidar")),
            ("too_few_points", arrays_to_pointcloud2(pts[:50], stamp_ns=1 * SEC, frame_id="lidar")),
            ("missing_frame", arrays_to_pointcloud2(good_s, stamp_ns=1 * SEC, frame_id="")),
        ]
        for k, (_, msg) in enumerate(cases):
            stamp = (10 + k) * SEC
            msg.header.stamp.sec, msg.header.stamp.nanosec = 10 + k, 0
            h.send("target_cloud", good_t, stamp)
            h.send_raw("source_cloud", msg)
            h.wait_processed(k + 1)
        # stamps that do not fit builtin_interfaces/Time (the pose could not carry them back) or whose
        # nanosec would carry into another second: refused at the input, with the malformed clouds
        for sec, nanosec in ((2147483647, 4294967295), (20, 1_000_000_000)):
            msg = arrays_to_pointcloud2(good_s, stamp_ns=0, frame_id="lidar")
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            cases.append(("malformed_cloud", msg))
            h.send("target_cloud", good_t, 20 * SEC)
            h.send_raw("source_cloud", msg)
            h.wait_processed(len(cases))
        # a source frame different from the one seen before on that input
        h.send("target_cloud", good_t, 30 * SEC)
        h.send("source_cloud", good_s, 30 * SEC)
        h.wait_processed(len(cases) + 1)
        h.send("target_cloud", good_t, 31 * SEC)
        h.send("source_cloud", good_s, 31 * SEC, frame="other_lidar")
        h.wait_processed(len(cases) + 2)
        s = h.node.stats()
        expected: dict[str, int] = {}
        for kind, _ in cases:
            expected[kind] = expected.get(kind, 0) + 1
        expected["mismatched_frame"] = 1
        assert s["errors"] == expected
        assert s["rejected"] == len(cases) + 1
        assert len(h.poses) == 1 and pose_stamped_to_matrix(h.poses[0])[1] == 30 * SEC  # only the good pair
        # still up: the next good pair is handled
        h.send("target_cloud", good_t, 40 * SEC)
        h.send("source_cloud", good_s, 40 * SEC)
        assert h.wait_for(lambda: len(h.poses) == 2)
        T, stamp, _ = pose_stamped_to_matrix(h.poses[1])
        assert stamp == 40 * SEC
        _check_pose(T, pose(0.8, 0.0, 0.0, np.deg2rad(2.0)))
    finally:
        h.close()


def test_odometry_mode_accumulates_and_resets(ros, world):
    h = Harness(tiny_config(**{"node.mode": "odometry", "node.odom_frame": "odom", "node.base_frame": ""}), "reg_odom")
    try:
        T_w = [at(0.9 * k, 0.05 * k, np.deg2rad(1.5 * k)) for k in range(4)]
        for k, T in enumerate(T_w):
            h.send("cloud", scan(world, T, seed=10 + k), (100 + k) * SEC // 10)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.poses) == 4)
        for k, msg in enumerate(h.poses):
            T, stamp, frame = pose_stamped_to_matrix(msg)
            assert frame == "odom" and stamp == (100 + k) * SEC // 10
            _check_pose(T, np.linalg.inv(T_w[0]) @ T_w[k], rot_deg=1.0 * max(k, 1), trans_m=0.3 * max(k, 1))
        assert h.transforms[-1].child_frame_id == "lidar"
        assert h.reset.wait_for_service(timeout_sec=5.0)
        fut = h.reset.call_async(Trigger.Request())
        assert h.wait_for(fut.done, 10.0) and fut.result().success
        h.send("cloud", scan(world, T_w[3], seed=20), 200 * SEC)
        assert h.wait_for(lambda: len(h.poses) == 5)
        np.testing.assert_allclose(pose_stamped_to_matrix(h.poses[4])[0], np.eye(4), atol=1e-9)
    finally:
        h.close()


def test_odometry_aligned_cloud_lines_up_in_the_odom_frame(ros, world):
    """Odometry mode's ~/aligned_cloud is the scan moved by T_odom_k into the odom frame and stamped with
    it: every scan overlays the first one (RViz, fixed frame odom), unlike the raw scans."""
    from rclpy.qos import qos_profile_sensor_data
    from scipy.spatial import cKDTree

    from msg_adapters.pointcloud2 import pointcloud2_to_xyz

    cfg = tiny_config(**{"node.mode": "odometry", "node.odom_frame": "odom", "node.publish_aligned_cloud": True})
    h = Harness(cfg, "reg_aligned")
    clouds: list[PointCloud2] = []
    h.client.create_subscription(PointCloud2, "/reg_aligned/aligned_cloud", clouds.append, qos_profile_sensor_data)
    try:
        T_w = [at(1.0 * k, 0.05 * k, np.deg2rad(2.0 * k)) for k in range(3)]
        xyz = [scan(world, T, seed=30 + k) for k, T in enumerate(T_w)]
        for k in range(3):
            h.send("cloud", xyz[k], (10 + k) * SEC // 10)
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(clouds) == 3 and len(h.poses) == 3), (len(clouds), h.node.stats())
        first = cKDTree(pointcloud2_to_xyz(clouds[0]))
        for k, msg in enumerate(clouds):
            assert msg.header.frame_id == "odom" and msg.header.stamp.sec * SEC + msg.header.stamp.nanosec == (
                (10 + k) * SEC // 10)
            T_odom = pose_stamped_to_matrix(h.poses[k])[0]
            pts = pointcloud2_to_xyz(msg)
            np.testing.assert_allclose(pts, xyz[k] @ T_odom[:3, :3].T + T_odom[:3, 3], atol=1e-3)
            if k:  # lines up with the first scan; the raw scan (what the cloud frame shows) does not
                aligned, raw = np.median(first.query(pts)[0]), np.median(first.query(xyz[k])[0])
                assert aligned < 0.5 * raw and aligned < 0.3, (k, aligned, raw)
    finally:
        h.close()


def test_node_declares_only_its_parameters_and_names_the_nearest(ros):
    """The node declares preprocess.*, registration.*, node.* (and odometry.* in odometry mode), never
    model.* / train.* / eval.*; flat KISS-ICP-style names are warnings naming the dotted parameter; a
    misspelt dotted name stops it with the nearest name."""
    from rclpy.parameter import Parameter

    cfg = tiny_config()
    flat = [Parameter("mode", value="odometry"), Parameter("base_frame", value="base_link"),
            Parameter("train.lr", value=0.1), Parameter("odometry.voxel_size", value=1.0),
            Parameter("qos_overrides./source_cloud.subscription.reliability", value="reliable")]
    node = RegistrationNode(cfg, registration=tiny_registration(cfg), node_name="reg_params",
                            parameter_overrides=flat)
    try:
        names = set(node._parameters)
        sections = {n.partition(".")[0] for n in names if "." in n and not n.startswith("qos_overrides.")}
        assert sections == {"preprocess", "registration", "node"}, sections
        assert "node.mode" in names and "node.publish_aligned_cloud" in names
        assert node.cfg.node.mode == "pair" and node.cfg.model == cfg.model  # flat names are not aliases
        text = "\n".join(node.parameter_warnings)
        assert "unknown parameter mode is ignored" in text and "did you mean node.mode?" in text
        assert "unknown parameter base_frame" in text and "did you mean node.base_frame?" in text
        assert "train.lr is ignored: a deepbbs-train setting" in text
        assert "odometry" not in text and "qos_overrides" not in text  # a note / rclpy's own parameters
        # the effective QoS, after qos_overrides (one QoS object per input: the override stays on its topic)
        assert node.input_qos == {"/source_cloud": "reliable/5", "/target_cloud": "best_effort/5"}
    finally:
        node.destroy_node()
    node = RegistrationNode(cfg, registration=tiny_registration(cfg), node_name="reg_params_odom",
                            parameter_overrides=[Parameter("node.mode", value="odometry")])
    try:
        assert {n.partition(".")[0] for n in node._parameters if "." in n} >= {"odometry"}
    finally:
        node.destroy_node()
    with pytest.raises(NodeError, match=r"unknown parameter node\.mod; did you mean node\.mode\?"):
        RegistrationNode(cfg, registration=tiny_registration(cfg), node_name="reg_params_bad",
                         parameter_overrides=[Parameter("node.mod", value="odometry")])


def test_params_file_applies_to_a_renamed_node(tmp_path):
    """config/deepbbs_ros.yaml is keyed by the /** wildcard: it applies whatever the node is renamed to."""
    import yaml
    from rclpy.context import Context

    from deepbbs_ros.node.registration_node import NODE_NAME

    shipped = yaml.safe_load((REPO / "config" / "deepbbs_ros.yaml").read_text())
    assert list(shipped) == ["/**"]
    shipped["/**"]["ros__parameters"]["node"]["slop"] = 0.123
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(shipped))
    ctx = Context()
    rclpy.init(args=["x", "--ros-args", "--params-file", str(path), "-r", "__node:=my_odom"], context=ctx)
    try:
        cfg = tiny_config()
        node = RegistrationNode(cfg, registration=tiny_registration(cfg), node_name=NODE_NAME, context=ctx)
        try:
            assert node.get_name() == "my_odom" and node.cfg.node.slop == 0.123
            assert node.parameter_warnings == []  # the shipped file sets only what the node declares
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_diagnostics_tick_on_the_wall_clock_with_sim_time(ros):
    """With use_sim_time and no /clock (a bag that ended) ROS time stands still; /diagnostics goes on."""
    from rclpy.parameter import Parameter

    cfg = tiny_config(**{"node.diagnostics_period": 0.2})
    h = Harness(cfg, "reg_simtime", parameter_overrides=[Parameter("use_sim_time", value=True)])
    try:
        assert h.node.get_clock().now().nanoseconds == 0  # no /clock: sim time is frozen at 0
        assert h.wait_for(lambda: len(h.diags) >= 3, 20.0), len(h.diags)
    finally:
        h.close()


class CountingRegistration:
    """The tiny registration, counting preprocess() calls, optionally slowed down (a busy machine)."""

    def __init__(self, reg, delay_s: float = 0.0) -> None:
        self.reg, self.delay_s, self.device = reg, delay_s, "cpu"
        self.preprocessed: list[int] = []

    def preprocess(self, xyz, times=None, stamp_ns=None):
        self.preprocessed.append(len(xyz))
        time.sleep(self.delay_s)
        return self.reg.preprocess(xyz, times, stamp_ns)

    def register(self, source, target):
        return self.reg.register(source, target)


@pytest.mark.parametrize("method", ["local_map", "scan_to_scan"])
def test_odometry_output_twist_covariance_tf(ros, world, method):
    """Odometry mode with every output: ~/odometry carries the pose, the twist (the motion since the
    previous scan over the stamp gap) and both covariances from the registration residuals; odom ->
    base_frame goes to the TF broadcaster (injected here; /tf over DDS: test_node_ros_stack.py). Scan to scan: each scan
    preprocessed exactly once, on arrival. Local map: nothing preprocessed on arrival; DeepBBS++ consulted
    on the first motion only (the previous and the current scan preprocessed then)."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.odom_frame": "odom", "node.base_frame": "base_link",
                         "node.publish_odometry": True, "node.publish_tf": True})  # fmt: skip
    counting = CountingRegistration(tiny_registration(cfg))
    tf: list[TransformStamped] = []
    h = Harness(cfg, f"reg_odom_out_{method}", registration=counting, tf_broadcaster=tf.extend,
                odometry_method=method)  # fmt: skip
    dt = 0.1
    try:
        T_w = [at(0.8 * k, 0.04 * k, np.deg2rad(1.2 * k)) for k in range(4)]
        stamps = [(300 + k) * SEC // 10 for k in range(4)]
        for k, T in enumerate(T_w):
            h.send("cloud", scan(world, T, seed=40 + k), stamps[k])
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.odoms) == 4 and len(tf) == 4), h.node.stats()
        if method == "scan_to_scan":
            assert counting.preprocessed == [N_POINTS] * 4  # once per scan: the source is reused as next target
        else:
            assert len(counting.preprocessed) == 2 and h.node.stats()["preprocess_cache"]["misses"] == 0
            assert (h.node.stats()["deepbbs_consulted"], h.node.odometry.odometry.deepbbs_calls) == (1, 1)
        prev_T, prev_trace = None, -1.0
        for k, msg in enumerate(h.odoms):
            T, stamp, frame, child = odometry_to_matrix(msg)
            assert (stamp, frame, child) == (stamps[k], "odom", "base_link")
            np.testing.assert_allclose(T, pose_stamped_to_matrix(h.poses[k])[0], atol=1e-9)
            T_tf, stamp_tf, frame_tf, child_tf = transform_stamped_to_matrix(tf[k])
            assert (stamp_tf, frame_tf, child_tf) == (stamps[k], "odom", "base_link")
            np.testing.assert_allclose(T_tf, T, atol=1e-9)
            twist, (pose_cov, twist_cov) = odometry_twist(msg), odometry_covariances(msg)
            assert np.allclose(pose_cov, pose_cov.T) and np.allclose(twist_cov, twist_cov.T)
            if k == 0:  # the origin: pose exact, velocity unknown
                assert not pose_cov.any() and not twist.any() and np.all(np.diag(twist_cov) >= 1e5)
            else:
                step = np.linalg.inv(prev_T) @ T
                gt_step = np.linalg.inv(T_w[k - 1]) @ T_w[k]
                np.testing.assert_allclose(twist, twist_from_delta(step, dt), atol=1e-6)
                v_gt = twist_from_delta(gt_step, dt)
                assert np.linalg.norm(twist[:3] - v_gt[:3]) <= 0.3 / dt  # the pose tolerance, per second
                assert np.linalg.norm(twist[3:] - v_gt[3:]) <= np.deg2rad(1.0) / dt
                for cov in (pose_cov, twist_cov):
                    assert np.all(np.diag(cov) > 0) and np.all(np.linalg.eigvalsh(cov) > -1e-12)
                assert np.trace(pose_cov) >= prev_trace  # accumulated along the trajectory
                assert np.all(np.diag(twist_cov) < 1e5)  # measured, unlike the origin's
            prev_T, prev_trace = T, float(np.trace(pose_cov))
    finally:
        h.close()


def test_odometry_mode_equals_replay_over_dds(ros):
    """The node's odometry mode over DDS gives replay's trajectory (``deepbbs-replay --mode odometry
    --method deepbbs++``) on the same motion-distorted toy drive: Velodyne-layout PointCloud2 with per-point
    times, published reliably one at a time (each answered before the next: no drop can change the
    trajectory). Same float32 inputs, same config: equal up to KISS-ICP's multi-threaded reductions
    (~1e-14) and the quaternion round trip of the PoseStamped (~1e-15)."""
    pytest.importorskip("kiss_icp")
    from deepbbs_ros.replay.methods import DeepBBSOdomMethod
    from deepbbs_ros.replay.runner import run_odometry
    from deepbbs_ros.replay.synthetic import synthetic_drive
    from msg_adapters.layouts import VELODYNE, build_cloud

    scans = synthetic_drive(15, motion_distortion=True)
    cfg = tiny_config(**{"node.mode": "odometry", "node.qos_reliability": "reliable", "node.publish_odometry": True})
    method = DeepBBSOdomMethod("deepbbs++", cfg, registration=tiny_registration(cfg))
    replay = run_odometry(scans, {"deepbbs++": method}, cfg)
    T_world = replay.T_world_est["deepbbs++"]
    want = [np.linalg.inv(T_world[0]) @ T for T in T_world]
    h = Harness(cfg, "reg_odom_replay")
    try:
        for k, s in enumerate(scans):
            p = s.points
            h.send_raw("cloud", build_cloud(VELODYNE, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2],
                                                       "intensity": s.fields["intensity"], "time": s.fields["time"]},
                                            stamp_ns=s.stamp_ns, frame_id=s.frame_id))  # fmt: skip
            h.wait_processed(k + 1)
        assert h.wait_for(lambda: len(h.poses) == len(scans) and len(h.odoms) == len(scans)), h.node.stats()
        st = h.node.stats()
        assert st["processed"] == len(scans) and st["errors"] == {} and st["dropped"] == 0
        for k, (msg, odom) in enumerate(zip(h.poses, h.odoms)):
            T, stamp, frame = pose_stamped_to_matrix(msg)
            assert (stamp, frame) == (scans[k].stamp_ns, "odom")
            np.testing.assert_allclose(T, want[k], rtol=0, atol=1e-6, err_msg=f"scan {k}")
            np.testing.assert_allclose(odometry_to_matrix(odom)[0], T, atol=1e-9)
    finally:
        h.close()


def test_busy_node_drops_oldest_clouds_and_counts(ros, world):
    """Preprocessing slower than the scan rate: the input queue stays bounded, the oldest waiting scans
    are dropped and counted on /diagnostics, and the node still answers the newest. (The scan-to-scan
    odometry preprocesses on arrival, which is what is slowed down here; the drop policy is the same
    for the local-map odometry.) One scan may wait (``node.odometry_backlog: 1``, the pair mode's policy)."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.diagnostics_period": 0.2, "node.odometry_backlog": 1})
    slow = CountingRegistration(tiny_registration(cfg), delay_s=0.6)
    h = Harness(cfg, "reg_busy", registration=slow, odometry_method="scan_to_scan")
    try:
        clouds = [scan(world, at(0.5 * k), seed=60 + k) for k in range(6)]
        h.send("cloud", clouds[0], 500 * SEC)
        assert h.wait_for(lambda: len(slow.preprocessed) == 1, 10)
        for k in range(1, 6):  # a 20 Hz burst while the first scan is being preprocessed
            h.send("cloud", clouds[k], 500 * SEC + k * SEC // 20)
            time.sleep(0.05)
        s = h.node.stats
        assert h.wait_for(lambda: s()["received"] == 6 and not h.node.worker.busy
                          and not any(i.busy for i in h.node.inputs), 30), s()  # fmt: skip
        st = s()
        assert st["input_dropped"][0] >= 3 and len(slow.preprocessed) == 6 - st["input_dropped"][0]
        assert st["processed"] + st["dropped"] + st["input_dropped"][0] == 6 and st["errors"] == {}
        assert h.wait_for(lambda: len(h.poses) == st["processed"], 10)
        assert pose_stamped_to_matrix(h.poses[-1])[1] == 500 * SEC + 5 * SEC // 20  # the newest scan answered
        key = "clouds dropped before preprocessing (oldest first)"
        assert h.wait_for(lambda: h.diagnostics().get(key) == str(st["input_dropped"][0]), 5), h.diagnostics()
    finally:
        h.close()


def test_odometry_backlog_answers_a_short_burst(ros, world):
    """Odometry mode's default backlog (6 scans): a transient (here the first scan's slow preprocessing, as the
    first motion is on a cold start) is answered late instead of leaving a gap: every scan of the burst gets a
    pose, in order."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.base_frame": ""})
    assert cfg.node.odometry_backlog == 6
    slow = CountingRegistration(tiny_registration(cfg), delay_s=0.6)
    h = Harness(cfg, "reg_backlog", registration=slow, odometry_method="scan_to_scan")
    try:
        clouds = [scan(world, at(0.5 * k), seed=70 + k) for k in range(7)]
        stamps = [600 * SEC + k * SEC // 10 for k in range(7)]
        h.send("cloud", clouds[0], stamps[0])
        assert h.wait_for(lambda: len(slow.preprocessed) == 1, 10)
        for k in range(1, 7):  # a 10 Hz burst while the first scan is being preprocessed
            h.send("cloud", clouds[k], stamps[k])
            time.sleep(0.1)
        assert h.wait_for(lambda: len(h.poses) == 7, 30), h.node.stats()
        assert [pose_stamped_to_matrix(m)[1] for m in h.poses] == stamps
        assert h.node.stats()["input_dropped"] == [0]
    finally:
        h.close()


def test_gicp_anchor_node_pair_mode(ros, world):
    """The GICP anchor of the latency benchmark: the same node and topics, small_gicp GICP inside."""
    pytest.importorskip("small_gicp")
    from deepbbs_ros.node.gicp_anchor import GicpRegistration

    cfg = tiny_config(**{"node.publish_odometry": True})
    h = Harness(cfg, "gicp_anchor_test", registration=GicpRegistration(cfg))
    try:
        T_w_tgt = at(10.0, 2.0, 0.1)
        T_w_src = T_w_tgt @ pose(1.0, 0.2, 0.0, np.deg2rad(3.0))
        h.send("target_cloud", scan(world, T_w_tgt, seed=1), 7 * SEC, "lidar")
        h.send("source_cloud", scan(world, T_w_src, seed=2), 7 * SEC, "lidar")
        assert h.wait_for(lambda: h.poses and h.odoms), h.node.stats()
        T, stamp, frame = pose_stamped_to_matrix(h.poses[0])
        assert (stamp, frame) == (7 * SEC, "lidar")
        _check_pose(T, np.linalg.inv(T_w_tgt) @ T_w_src)
        cov = odometry_covariances(h.odoms[0])[0]
        assert np.all(np.diag(cov) > 0) and h.node.stats()["errors"] == {}
        h.send("target_cloud", scan(world, T_w_src, seed=2), 7 * SEC + SEC // 10, "lidar")  # the next pair: the
        h.send("source_cloud", scan(world, T_w_src @ pose(1.0, 0.0, 0.0, 0.0), seed=3), 7 * SEC + SEC // 10, "lidar")
        assert h.wait_for(lambda: len(h.poses) == 2), h.node.stats()  # anchor still starts from identity
        assert h.node.stats()["errors"] == {} and h.node.stats()["paths"] == {"gicp": 0, "deepbbs": 0, "search": 0}
    finally:
        h.close()


@pytest.mark.parametrize(
    "overrides, match",
    [
        ({"node.odom_frame": "/odom"}, r"node.odom_frame: invalid frame id '/odom'"),
        ({"node.base_frame": "base link"}, r"node.base_frame: invalid frame id"),
        ({"node.mode": "odometry", "node.publish_tf": True}, r"tf2_msgs"),  # pair mode broadcasts only with pair_tf
    ],
)
def test_startup_errors_in_process(ros, overrides, match):
    cfg = tiny_config(**overrides)
    if overrides.get("node.publish_tf"):
        pytest.importorskip("sys")  # always there; the check below decides
        try:
            import tf2_msgs  # noqa: F401

            pytest.skip("tf2_msgs is installed here: publish_tf works")
        except ImportError:
            pass
    with pytest.raises(NodeError, match=match):
        RegistrationNode(cfg, registration=tiny_registration(cfg), node_name="reg_err")


@pytest.mark.parametrize(
    "name, value, match",
    [
        ("registration.device", "tpu", r"registration.device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got 'tpu'"),
        ("node.mode", "stereo", r"node.mode must be 'pair' or 'odometry', got 'stereo'"),
        ("node.slop", -1.0, r"node.slop must be >= 0"),
    ],
)
def test_bad_parameters_in_process(ros, name, value, match):
    from rclpy.parameter import Parameter

    cfg = tiny_config()
    with pytest.raises(NodeError, match=match):
        RegistrationNode(cfg, node_name="reg_param", parameter_overrides=[Parameter(name, value=value)])


def _run_cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "deepbbs_ros.node.registration_node", *args],
        capture_output=True, text=True, timeout=timeout,
    )


@pytest.mark.parametrize(
    "args, match",
    [
        (["--ros-args", "-p", "registration.weights:=/nonexistent/w.pt"], r"registration.weights: file not found"),
        (["--ros-args", "-r", "source_cloud:=bad topic"], r"source_cloud|topic|remap|bad topic"),
        (["--ros-args", "-p", "node.mod:=odometry"], r"deepbbs-node: error: unknown parameter node\.mod; "
                                                     r"did you mean node\.mode\?"),
        # KISS-ICP-style flat names: a warning naming the dotted parameter, printed before the model loads
        (["--ros-args", "-p", "mode:=odometry", "-p", "base_frame:=base_link", "-p", "registration.weights:=/no/w.pt"],
         r"(?s)unknown parameter base_frame is ignored .*did you mean node\.base_frame\?.*"
         r"unknown parameter mode is ignored .*did you mean node\.mode\?.*registration.weights: file not found"),
    ],
)
def test_cli_startup_errors(tmp_path, args, match):
    res = _run_cli(*args)
    assert res.returncode != 0, res.stderr
    assert "Traceback" not in res.stderr, res.stderr
    import re

    assert re.search(match, res.stderr), res.stderr


def _node_process(*ros_args: str, module: str = "deepbbs_ros.node.gicp_anchor") -> subprocess.Popen:
    """A node in its own process (the GICP anchor by default: run_node and RegistrationNode as deepbbs-node,
    ready in about a second), its log merged on stdout."""
    return subprocess.Popen([sys.executable, "-m", module, "--ros-args", *ros_args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def _stop(proc: subprocess.Popen, sig, ready: str = "ready in", timeout: float = 120.0) -> tuple[int, str]:
    """Wait for the ``ready`` log line, send ``sig``, return (exit code, whole log)."""
    lines, deadline = [], time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if ready in line:
                break
        assert any(ready in line for line in lines), "".join(lines)
        proc.send_signal(sig)
        rest, _ = proc.communicate(timeout=60)
    finally:
        proc.kill() if proc.poll() is None else None
    return proc.returncode, "".join(lines) + (rest or "")


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_node_process_stops_quietly(sig):
    """SIGINT / SIGTERM: exit code 0, the node's last line ('stopping: ...' with its counts) logged, and nothing
    else: no 'Failed to publish log message to rosout' (the context shut down under the logger), no traceback."""
    import signal

    code, log = _stop(_node_process("-r", "source_cloud:=/quiet/a", "-r", "target_cloud:=/quiet/b"),
                      getattr(signal, sig))
    assert code == 0, log
    assert "stopping: 0 clouds received" in log, log
    assert "Failed to publish" not in log and "rosout" not in log and "Traceback" not in log, log


def test_remap_matching_no_topic_is_a_warning_naming_the_inputs(ros):
    """rclpy ignores a remap whose name is none of the node's topics; the node says so, before it loads
    anything, naming its inputs: KISS-ICP's pointcloud_topic in pair mode, a misspelt input, the other mode's."""
    import signal

    code, log = _stop(_node_process("-r", "pointcloud_topic:=/rmp/points", "-r", "source_clouds:=/rmp/a",
                                    "-r", "target_cloud:=/rmp/b", "-r", "~/pose:=/rmp/pose",
                                    "-r", "other_node:cloud:=/rmp/c"), signal.SIGINT)  # fmt: skip
    assert code == 0, log
    warnings = [line for line in log.splitlines() if "matches no topic" in line]
    assert len(warnings) == 2, log  # target_cloud, ~/pose and another node's rule are fine
    assert ("remap pointcloud_topic:=/rmp/points matches no topic of this node and is ignored: its inputs are "
            "source_cloud, target_cloud (node.mode=pair); pointcloud_topic (KISS-ICP's input name) is an input of "
            "node.mode odometry (-p node.mode:=odometry)") in warnings[0], warnings
    assert "remap source_clouds:=/rmp/a" in warnings[1] and "did you mean source_cloud:=/rmp/a?" in warnings[1]
    assert log.index("matches no topic") < log.index("ready in")  # said before the start-up's work
    # the launch file remaps every input, the other mode's to itself by default: no warning for those
    code, log = _stop(_node_process("-p", "node.mode:=odometry", "-r", "source_cloud:=/rmp/a",
                                    "-r", "target_cloud:=target_cloud"), signal.SIGINT)
    assert log.count("matches no topic") == 1, log
    assert code == 0 and "source_cloud is an input of node.mode pair (-p node.mode:=pair)" in log, log
    assert "its inputs are cloud (or pointcloud_topic, KISS-ICP's name) (node.mode=odometry)" in log, log


def test_pointcloud_topic_is_the_odometry_input_kiss_icp_style(ros):
    """``-r pointcloud_topic:=/points`` (KISS-ICP's input) feeds odometry mode: the node subscribes the remapped
    topic (seen on the DDS graph) with no warning."""
    import signal

    listener = rclpy.create_node("rmp_listener")
    proc = _node_process("-p", "node.mode:=odometry", "-r", "pointcloud_topic:=/rmp_kiss/points")
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and listener.count_subscribers("/rmp_kiss/points") == 0:
            rclpy.spin_once(listener, timeout_sec=0.1)
        assert listener.count_subscribers("/rmp_kiss/points") == 1
        assert listener.count_subscribers("/cloud") == 0 and listener.count_subscribers("/pointcloud_topic") == 0
        code, log = _stop(proc, signal.SIGTERM)
    finally:
        proc.kill() if proc.poll() is None else None
        listener.destroy_node()
    assert code == 0 and "inputs=[/rmp_kiss/points]" in log and "WARN" not in log, log
