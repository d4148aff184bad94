"""The node's threads and pipeline without DDS: bounded queues, the preprocessing cache, the input
stage (decode, checks, drops), scan-to-scan odometry, the twist covariance, and the local-map odometry
(the node's default) against replay's on the same recording.

Messages are rosbags-flavoured PointCloud2 (no rclpy needed); registration is a stub that returns
known transforms, so every figure of the first part is exact or a Monte Carlo check of an equation.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.covariance import adjoint, skew, twist_covariance, twist_from_delta
from deepbbs_ros.node.inputs import BadInput, Cloud, CloudInput, decode_cloud
from deepbbs_ros.node.pipeline import UNKNOWN_TWIST_COV, ScanToScanOdometry
from deepbbs_ros.node.preprocess_cache import PreprocessCache
from deepbbs_ros.node.worker import LatestSlotWorker
from deepbbs_ros.replay.synthetic import pose
from msg_adapters.layouts import OUSTER, VELODYNE, build_cloud
from msg_adapters.pointcloud2 import arrays_to_pointcloud2

SEC = 1_000_000_000


def _cloud_msg(xyz: np.ndarray, stamp_ns: int, frame: str = "lidar"):
    return arrays_to_pointcloud2(xyz, stamp_ns=stamp_ns, frame_id=frame, flavor="rosbags")


def _points(seed: int, n: int = 500) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-20, 20, (n, 3)).astype(np.float32)


# -- the bounded worker --------------------------------------------------------------------------------
def _gated_worker(capacity: int):
    gate, started, done = threading.Event(), threading.Event(), []

    def handler(job):
        started.set()
        gate.wait(5)
        done.append(job)

    return LatestSlotWorker(handler, capacity=capacity), gate, started, done


@pytest.mark.parametrize("capacity, kept", [(1, [0, 5]), (2, [0, 4, 5]), (4, [0, 2, 3, 4, 5])])
def test_worker_drops_the_oldest_waiting_jobs(capacity, kept):
    w, gate, started, done = _gated_worker(capacity)
    try:
        w.submit(0)
        assert started.wait(5)  # job 0 runs and blocks: 1..5 queue behind it
        for j in range(1, 6):
            w.submit(j)
        gate.set()
        assert w.wait_idle(5)
        assert done == kept  # in order, newest kept
        assert w.dropped == 5 - (len(kept) - 1) and w.submitted == 6 and w.processed == len(kept)
    finally:
        w.stop()


def test_gated_worker_waits_for_room_downstream():
    downstream, gate, started, _ = _gated_worker(1)
    done = []
    up = LatestSlotWorker(done.append, capacity=1, gate=downstream.room)
    try:
        downstream.submit("running")
        assert started.wait(5)
        downstream.submit("waiting")  # downstream full: its room closes, upstream holds its jobs
        assert not downstream.room.is_set()
        for j in range(3):
            up.submit(j)
        time.sleep(0.2)
        assert done == [] and up.busy and up.dropped == 2  # only the newest is kept
        gate.set()  # downstream takes its waiting job: room again
        assert up.wait_idle(5) and done == [2]
    finally:
        gate.set()
        up.stop()
        downstream.stop()


def test_worker_survives_a_failing_job():
    errors = []

    def handler(job):
        if job == "bad":
            raise ValueError("boom")

    w = LatestSlotWorker(handler, lambda job, exc: errors.append((job, str(exc))))
    try:
        w.submit("bad")
        assert w.wait_idle(5)
        w.submit("good")
        assert w.wait_idle(5)
        assert errors == [("bad", "boom")] and w.processed == 2
    finally:
        w.stop()


# -- the preprocessing cache ---------------------------------------------------------------------------
def test_cache_computes_each_content_once_even_concurrently():
    calls = []

    def slow(xyz, times=None, stamp_ns=None):
        calls.append(len(xyz))
        time.sleep(0.2)
        return xyz.sum()

    cache = PreprocessCache(slow, size=2)
    a, b = _points(0), _points(1)
    out = []
    threads = [threading.Thread(target=lambda: out.append(cache.get(a.copy(), "a"))) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and all(r == a.sum() for r, _ in out)
    assert sorted(ms > 0 for _, ms in out) == [False, False, True]  # only the thread that computed it
    cache.get(b, "b")
    cache.get(_points(2), "c")  # evicts a (least recently used)
    cache.get(a, "a")
    assert len(calls) == 4 and (cache.hits, cache.misses) == (2, 4)


def test_cache_does_not_keep_failures():
    n = []

    def fails(xyz, times=None, stamp_ns=None):
        n.append(1)
        raise RegistrationError("too few points after cropping")

    cache = PreprocessCache(fails)
    for _ in range(2):
        with pytest.raises(BadInput, match="scan@1: too few points") as err:
            cache.get(_points(0), "scan@1")
        assert err.value.kind == "preprocess_failed"
    assert len(n) == 2


# -- decoding ------------------------------------------------------------------------------------------
def test_decode_reads_driver_time_fields_in_seconds():
    xyz = _points(3, 10)
    vel = build_cloud(VELODYNE, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                 "time": np.linspace(0, 0.099, 10, dtype=np.float32)}, flavor="rosbags")  # fmt: skip
    got, times, _, _ = decode_cloud(vel, "/v", 3)
    np.testing.assert_array_equal(got, xyz)
    np.testing.assert_allclose(times, np.linspace(0, 0.099, 10), atol=1e-7)
    ost = build_cloud(OUSTER, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                               "t": np.arange(10, dtype=np.uint32) * 97_656}, height=2, flavor="rosbags")  # fmt: skip
    _, times, _, _ = decode_cloud(ost, "/o", 3)
    np.testing.assert_allclose(times, np.arange(10) * 97_656e-9)
    assert decode_cloud(_cloud_msg(xyz, 5), "/p", 3)[1] is None


def test_decode_a_time_field_with_one_value_is_no_time():
    # KITTI-style clouds in a driver layout: the time field is there but 0 for every point (no per-point timing)
    xyz = _points(3, 10)
    for layout, name, value in ((VELODYNE, "time", np.float32(0)), (OUSTER, "t", np.uint32(0)),
                                (VELODYNE, "time", np.float32(0.05))):  # fmt: skip
        msg = build_cloud(layout, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], name: np.full(10, value)},
                          flavor="rosbags")  # fmt: skip
        got, times, _, _ = decode_cloud(msg, "/v", 3)
        np.testing.assert_array_equal(got, xyz)
        assert times is None


# -- the input stage -----------------------------------------------------------------------------------
class _Sink:
    def __init__(self) -> None:
        self.clouds: list[Cloud] = []
        self.bad: list[tuple[str, str]] = []
        self.errors: list[BaseException] = []


def _input(preprocess, sink: _Sink, **kw) -> CloudInput:
    return CloudInput("/cloud", PreprocessCache(preprocess), 100, sink.clouds.append,
                      lambda kind, msg: sink.bad.append((kind, msg)), lambda job, exc: sink.errors.append(exc),
                      **kw)  # fmt: skip


def test_input_drops_the_oldest_when_busy_and_counts():
    started = threading.Event()

    def slow(xyz, times=None, stamp_ns=None):
        started.set()
        time.sleep(0.3)
        return xyz.mean(axis=0)

    sink = _Sink()
    inp = _input(slow, sink)
    try:
        inp.submit(_cloud_msg(_points(0), 0), time.perf_counter())
        assert started.wait(5)
        for k in range(1, 6):  # a burst while busy: each one replaces the waiting one
            inp.submit(_cloud_msg(_points(k), k * SEC), time.perf_counter())
        deadline = time.monotonic() + 10
        while inp.busy and time.monotonic() < deadline:
            time.sleep(0.02)
        assert [c.stamp_ns for c in sink.clouds] == [0, 5 * SEC]
        assert inp.dropped == 4 and not sink.bad and not sink.errors
        c = sink.clouds[-1]
        np.testing.assert_allclose(c.pp, _points(5).mean(axis=0))  # the cloud's own preprocessing
        assert c.timings_ms["preprocess"] >= 250 and c.t_ready >= c.t_recv
    finally:
        inp.stop()


def test_input_rejects_bad_messages_and_goes_on():
    sink = _Sink()
    inp = _input(lambda xyz, *_: xyz[:10], sink, increasing_stamps=True)
    msgs = [
        _cloud_msg(_points(0), 2 * SEC),
        _cloud_msg(_points(1), 2 * SEC),  # same stamp again
        _cloud_msg(_points(2), 3 * SEC, frame="other"),  # frame changed
        _cloud_msg(_points(3, 50), 4 * SEC),  # too few points
        _cloud_msg(np.full((500, 3), np.nan, np.float32), 5 * SEC),
        _cloud_msg(_points(4), 6 * SEC),
    ]
    try:
        for m in msgs:
            inp.submit(m, time.perf_counter())
            deadline = time.monotonic() + 5
            while inp.busy and time.monotonic() < deadline:
                time.sleep(0.005)
        assert [c.stamp_ns for c in sink.clouds] == [2 * SEC, 6 * SEC]
        assert [k for k, _ in sink.bad] == ["stamp_not_increasing", "mismatched_frame", "too_few_points",
                                            "no_valid_points"]  # fmt: skip
        assert all("/cloud" in m for _, m in sink.bad)
        inp.reset()  # forgets frame and stamp
        inp.submit(_cloud_msg(_points(5), 1 * SEC, frame="other"), time.perf_counter())
        deadline = time.monotonic() + 5
        while len(sink.clouds) < 3 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert sink.clouds[-1].frame_id == "other" and len(sink.bad) == 4
    finally:
        inp.stop()


# -- scan-to-scan odometry -----------------------------------------------------------------------------
class _KnownMotion:
    """register() returns T_target_source from ground-truth poses keyed by the clouds' first point."""

    def __init__(self, poses: dict[float, np.ndarray]) -> None:
        self.poses = poses
        self.calls = 0

    def preprocess(self, xyz, times=None, stamp_ns=None):  # the node's cache calls this on arrival
        raise AssertionError("odometry must not preprocess: the input stage did")

    def register(self, source, target):
        self.calls += 1
        T = np.linalg.inv(self.poses[float(target.points[0, 0])]) @ self.poses[float(source.points[0, 0])]

        class R:
            T_target_source = T
            converged = True
            gamma = None

        return R()


class _PP:
    def __init__(self, points: np.ndarray) -> None:
        self.points = points


def test_scan_to_scan_odometry_pose_twist_covariance():
    rng = np.random.default_rng(7)
    poses, clouds = {}, []
    dt = 0.1
    for k in range(5):
        T = pose(1.0 * k, 0.1 * k**2, 0.0, np.deg2rad(2.0 * k))
        pts = rng.uniform(-30, 30, (400, 3))
        pts[:, 2] = rng.uniform(-2, 5, 400)
        pts[0, 0] = 1000.0 + k  # the stub's key
        poses[pts[0, 0]] = T
        clouds.append(Cloud(pts.astype(np.float32), int(k * dt * SEC), "lidar", 0.0, pp=_PP(pts)))
    # source points of step k seen from scan k-1 land exactly on... nothing (random clouds): the
    # covariance is then the residual one; what is checked is its shape, growth and frame change
    reg = _KnownMotion(poses)
    odo = ScanToScanOdometry(reg)
    first = odo.step(clouds[0])
    np.testing.assert_array_equal(first.T_odom, np.eye(4))
    assert not first.pose_covariance.any() and np.allclose(first.twist_covariance, np.eye(6) * UNKNOWN_TWIST_COV)
    traces = [0.0]
    for k in range(1, 5):
        est = odo.step(clouds[k])
        T_gt = np.linalg.inv(poses[1000.0]) @ poses[1000.0 + k]
        np.testing.assert_allclose(est.T_odom, T_gt, atol=1e-12)
        delta = np.linalg.inv(poses[1000.0 + k - 1]) @ poses[1000.0 + k]
        np.testing.assert_allclose(est.T_prev_curr, delta, atol=1e-12)
        np.testing.assert_allclose(est.twist, twist_from_delta(delta, dt), atol=1e-9)
        for cov in (est.pose_covariance, est.twist_covariance):
            assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
        traces.append(float(np.trace(est.pose_covariance)))
    assert traces == sorted(traces) and traces[-1] > 0  # accumulated, never shrinking
    assert reg.calls == 4
    odo.reset()
    np.testing.assert_array_equal(odo.step(clouds[3]).T_odom, np.eye(4))


def test_twist_covariance_matches_monte_carlo():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    T = pose(1.2, -0.3, 0.05, np.deg2rad(8.0))
    A = rng.normal(size=(6, 6))
    cov = A @ A.T * 1e-6  # registration covariance, left perturbation in the previous frame
    dt = 0.1
    samples = rng.multivariate_normal(np.zeros(6), cov, 40_000)
    tw = []
    for d in samples:  # T' = exp(delta) T with delta = [dt (3), dtheta (3)]
        Rd = Rotation.from_rotvec(d[3:]).as_matrix()
        Tp = np.eye(4)
        Tp[:3, :3] = Rd @ T[:3, :3]
        Tp[:3, 3] = Rd @ T[:3, 3] + d[:3]
        tw.append(twist_from_delta(Tp, dt))
    mc = np.cov(np.asarray(tw).T)
    pred = twist_covariance(T, cov, dt)
    np.testing.assert_allclose(pred, mc, atol=0.05 * np.abs(pred).max())
    # with no motion the frame change is the identity
    np.testing.assert_allclose(twist_covariance(np.eye(4), cov, dt), cov / dt**2)
    assert np.allclose(adjoint(np.eye(4)), np.eye(6)) and np.allclose(skew(np.array([1.0, 2, 3])) @ [1, 2, 3], 0)


# -- local-map odometry: the node's odometry is replay's ---------------------------------------------------
TINY = {  # a small random network, refinement only: the comparison does not depend on trained weights
    "model.k": 8, "model.dgcnn_widths": [16, 32], "model.emb_dims": 32, "model.n_heads": 2, "model.ff_dims": 64,
    "preprocess.num_points": 512, "registration.deep": False, "registration.refine": True,
    "registration.polish": "none", "registration.device": "cpu",
}  # fmt: skip


def _tiny_registration(cfg):
    import torch

    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.core.registration import DeepBBSRegistration

    torch.manual_seed(0)
    return DeepBBSRegistration(cfg, model=DeepBBSNet(cfg.model).eval(), device="cpu")


class _Counting:
    """A registration counting preprocess() calls (the local-map odometry preprocesses only when it
    consults DeepBBS++)."""

    def __init__(self, reg) -> None:
        self.reg, self.preprocessed = reg, 0

    def preprocess(self, xyz, times=None, stamp_ns=None):
        self.preprocessed += 1
        return self.reg.preprocess(xyz, times, stamp_ns)

    def register(self, source, target):
        return self.reg.register(source, target)


def test_node_odometry_equals_replay_on_a_recording(tmp_path):
    """A motion-distorted toy drive written to a bag: ``deepbbs-replay --mode odometry --method deepbbs++``
    (DeepBBSOdomMethod over the bag) and the node's odometry path (each scan as a Velodyne-layout
    PointCloud2 through the node's input thread: decode, per-point times, stamps, checks, no
    preprocessing on arrival; then LocalMapOdometry.step) give the same poses. The inputs are the same
    float32 points and times, so the only difference allowed is KISS-ICP's multi-threaded reductions
    (summation order: ~1e-14 measured); 1e-6 m/rad leaves room for that."""
    pytest.importorskip("kiss_icp")
    pytest.importorskip("small_gicp")
    from deepbbs_ros.config import Config
    from deepbbs_ros.datasets import open_source, write_scans
    from deepbbs_ros.node.pipeline import LocalMapOdometry
    from deepbbs_ros.replay.methods import DeepBBSOdomMethod
    from deepbbs_ros.replay.runner import run_odometry
    from deepbbs_ros.replay.synthetic import synthetic_drive

    scans = synthetic_drive(15, motion_distortion=True)
    bag = tmp_path / "drive"
    write_scans(scans, bag, "mcap")
    cfg = Config().replace(**TINY)

    # replay, from the bag
    replay = run_odometry(open_source(bag), {"deepbbs++": DeepBBSOdomMethod("deepbbs++", cfg,
                                                                             registration=_tiny_registration(cfg))},
                          cfg)  # fmt: skip
    assert replay.failed["deepbbs++"] == []
    T_world = replay.T_world_est["deepbbs++"]
    want = [np.linalg.inv(T_world[0]) @ T for T in T_world]

    # the node: Velodyne-layout messages through its input thread, then its odometry
    sink = _Sink()
    inp = CloudInput("/cloud", None, 100, sink.clouds.append, lambda kind, msg: sink.bad.append((kind, msg)),
                     lambda job, exc: sink.errors.append(exc), increasing_stamps=True)  # fmt: skip
    reg = _Counting(_tiny_registration(cfg))
    odo = LocalMapOdometry(cfg, reg)
    got, steps = [], []
    try:
        for s in scans:
            p = s.points
            msg = build_cloud(VELODYNE, {"x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "intensity": s.fields["intensity"],
                                         "time": s.fields["time"]},
                              flavor="rosbags", stamp_ns=s.stamp_ns, frame_id=s.frame_id)  # fmt: skip
            n = len(sink.clouds)
            inp.submit(msg, time.perf_counter())
            deadline = time.monotonic() + 10
            while len(sink.clouds) == n and time.monotonic() < deadline and not sink.bad and not sink.errors:
                time.sleep(0.002)
            assert not sink.bad and not sink.errors and len(sink.clouds) == n + 1
            cloud = sink.clouds[-1]
            assert cloud.pp is None and "preprocess" not in cloud.timings_ms  # nothing preprocessed on arrival
            assert cloud.stamp_ns == s.stamp_ns and cloud.times is not None
            est = odo.step(cloud)
            got.append(est.T_odom)
            steps.append(est)
    finally:
        inp.stop()
    assert inp.dropped == 0
    for k, (T_node, T_replay) in enumerate(zip(got, want)):
        np.testing.assert_allclose(T_node, T_replay, rtol=0, atol=1e-6, err_msg=f"scan {k}")
    # DeepBBS++ was consulted on the first motion only (previous and current scan preprocessed then)
    assert odo.consulted == 1 and reg.preprocessed == 2
    # the drive itself: within a few cm of ground truth (deskewed; the toy world overlaps exactly)
    gt = [np.linalg.inv(scans[0].T_world_lidar) @ s.T_world_lidar for s in scans]
    assert max(np.linalg.norm(T[:3, 3] - G[:3, 3]) for T, G in zip(got, gt)) < 0.1
    # twist from the step over the stamp gap; covariances symmetric positive definite, pose one accumulated
    assert np.allclose(steps[0].twist_covariance, np.eye(6) * UNKNOWN_TWIST_COV) and not steps[0].pose_covariance.any()
    traces = []
    for k in range(1, len(steps)):
        est, dt = steps[k], (scans[k].stamp_ns - scans[k - 1].stamp_ns) * 1e-9
        np.testing.assert_allclose(est.T_prev_curr, np.linalg.inv(got[k - 1]) @ got[k], atol=1e-9)
        np.testing.assert_allclose(est.twist, twist_from_delta(est.T_prev_curr, dt), atol=1e-9)
        for cov in (est.pose_covariance, est.twist_covariance):
            assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
        assert np.all(np.diag(est.twist_covariance) < 1e3)
        traces.append(float(np.trace(est.pose_covariance)))
        assert {"register", "register.align", "covariance"} <= set(est.registered.timings_ms)
    assert traces == sorted(traces)
    odo.reset()  # the next scan is the origin again
    np.testing.assert_array_equal(odo.step(sink.clouds[5]).T_odom, np.eye(4))


def test_node_odometry_bridges_a_dropped_scan_without_deepbbs():
    """The node's odometry on a stream where the node dropped scans (one, then two in a row, as a busy node
    does): GICP from the prediction scaled to the stamp gap answers the next scans; DeepBBS++ runs at the first
    motion only (two scans preprocessed for it), so a dropped scan does not make the next step slower, and
    the poses stay on the ground truth."""
    pytest.importorskip("kiss_icp")
    pytest.importorskip("small_gicp")
    from deepbbs_ros.config import Config
    from deepbbs_ros.node.pipeline import LocalMapOdometry
    from deepbbs_ros.replay.synthetic import synthetic_drive

    scans = synthetic_drive(14, motion_distortion=True)
    cfg = Config().replace(**TINY)
    reg = _Counting(_tiny_registration(cfg))
    odo = LocalMapOdometry(cfg, reg)
    kept = [k for k in range(len(scans)) if k not in (5, 9, 10)]
    for k in kept:
        s = scans[k]
        est = odo.step(Cloud(s.points.astype(np.float32), s.stamp_ns, s.frame_id, time.perf_counter(),
                             np.asarray(s.fields["time"], np.float64)))
        if k in (6, 11):  # the scans after a gap of 2 and 3 periods
            assert not est.registered.result.deepbbs and est.dt == pytest.approx((3 if k == 11 else 2) * 0.1)
        gt = np.linalg.inv(scans[0].T_world_lidar) @ s.T_world_lidar
        assert np.linalg.norm(est.T_odom[:3, 3] - gt[:3, 3]) < 0.1, k
    assert odo.consulted == 1 and reg.preprocessed == 2


def test_input_follows_its_topics_velocity_and_deskews():
    """node.pair_deskew: an input with a StreamDeskew hands on raw sweeps (per-point ``time``) with a deskewed
    GICP cloud from the second scan on, the velocity being the toy drive's 1.5 m per scan."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.deskew import StreamDeskew
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.replay.synthetic import synthetic_drive

    reg = DeepBBSRegistration(Config().replace(**{"registration.device": "cpu", "registration.threads": 1}))
    scans = synthetic_drive(frames=3, seed=4, speed=15.0, motion_distortion=True)
    sink = _Sink()
    inp = CloudInput("/cloud", PreprocessCache(reg.preprocess), 100, sink.clouds.append,
                     lambda kind, msg: sink.bad.append((kind, msg)), lambda job, exc: sink.errors.append(exc),
                     deskew=StreamDeskew(reg))  # fmt: skip
    try:
        for s in scans:
            inp.submit(arrays_to_pointcloud2(s.points, {"time": s.fields["time"]}, stamp_ns=s.stamp_ns,
                                             frame_id="lidar", flavor="rosbags"), time.perf_counter())
            deadline = time.monotonic() + 30
            while inp.busy and time.monotonic() < deadline:
                time.sleep(0.02)
    finally:
        inp.stop()
    assert not sink.bad and not sink.errors and len(sink.clouds) == 3
    assert sink.clouds[0].pp.deskewed_cloud is None and sink.clouds[0].pp.deskew.startswith("no velocity yet")
    for c in sink.clouds[1:]:
        assert c.pp.deskew == "deskewed" and abs(c.pp.velocity[0][0, 3] - 1.5) < 0.02 and c.pp.velocity[1] == 0.1


def test_node_deep_passes_replace_the_registrations_in_pair_mode_only():
    """node.deep_passes sets the network passes of the node's DeepBBS++ in pair mode (0 keeps
    registration.max_deep_iters); odometry mode and the caller's config are left alone."""
    from deepbbs_ros.config import Config, NodeConfig, RegistrationConfig
    from deepbbs_ros.errors import ConfigError
    from deepbbs_ros.node.parameters import node_registration_config

    cfg = Config(registration=RegistrationConfig(max_deep_iters=3), node=NodeConfig(mode="pair", deep_passes=1))
    out = node_registration_config(cfg)
    assert out.registration.max_deep_iters == 1 and cfg.registration.max_deep_iters == 3
    assert out.node == cfg.node and out.preprocess == cfg.preprocess
    for node in (NodeConfig(mode="pair", deep_passes=0), NodeConfig(mode="odometry", deep_passes=1)):
        other = node_registration_config(Config(registration=cfg.registration, node=node))
        assert other.registration.max_deep_iters == 3
    with pytest.raises(ConfigError, match="node.deep_passes"):
        Config(node=NodeConfig(deep_passes=-1)).validate()


def test_node_polish_max_voxels_caps_the_gicp_clouds_in_pair_mode_only():
    """node.polish_max_voxels (off by default) becomes registration.polish_max_voxels of the pair-mode node."""
    from deepbbs_ros.config import Config, NodeConfig
    from deepbbs_ros.errors import ConfigError
    from deepbbs_ros.node.parameters import node_registration_config

    assert node_registration_config(Config()).registration.polish_max_voxels == 0
    out = node_registration_config(Config(node=NodeConfig(mode="pair", polish_max_voxels=9000)))
    assert out.registration.polish_max_voxels == 9000 and out.registration.max_deep_iters == 1
    odo = node_registration_config(Config(node=NodeConfig(mode="odometry", polish_max_voxels=9000)))
    assert odo.registration.polish_max_voxels == 0
    with pytest.raises(ConfigError, match="node.polish_max_voxels"):
        Config(node=NodeConfig(polish_max_voxels=-1)).validate()
