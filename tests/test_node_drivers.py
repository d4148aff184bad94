"""The node knows its LiDAR driver: per-point times of Livox / Hesai absolute ``timestamp`` fields, the driver
recognised per input topic and passed to the preprocessing (``preprocess.sensor: auto``), logged and on
/diagnostics. Real rclpy over real DDS for the node (the harness of test_node.py)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()  # before the first DDS participant of this process

rclpy = pytest.importorskip("rclpy")

import test_node  # noqa: E402
from test_node import Harness, at, scan, tiny_config, tiny_registration  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.datasets.base import Scan  # noqa: E402
from deepbbs_ros.node.inputs import CloudInput, decode_cloud  # noqa: E402
from deepbbs_ros.node.preprocess_cache import PreprocessCache  # noqa: E402
from msg_adapters.layouts import driver_cloud  # noqa: E402

ros = test_node.ros  # the module fixture: rclpy context
world = test_node.world  # the structured street

SEC = 1_000_000_000
STAMP = 1_700_000_000_123_456_789  # an absolute stamp as drivers write it (ns since the epoch)


def _points(seed: int, n: int = 400) -> np.ndarray:
    return (np.random.default_rng(seed).normal(size=(n, 3)) * 8).astype(np.float32)


def _driver_msg(driver: str, xyz: np.ndarray, rel: np.ndarray, stamp_ns: int = STAMP, flavor: str = "rclpy"):
    """``xyz`` as ``driver`` publishes it, its points measured ``rel`` s after ``stamp_ns``; -> (msg, fields)."""
    n = len(xyz)
    f = {"intensity": np.ones(n, np.float32)}
    if driver == "livox":  # float64 absolute ns
        f.update(line=np.arange(n, dtype=np.uint8) % 6, timestamp=stamp_ns + rel * 1e9)
    elif driver == "hesai":  # float64 absolute s
        f.update(ring=np.arange(n, dtype=np.uint16) % 32, timestamp=stamp_ns * 1e-9 + rel)
    else:  # velodyne: float32 s since the stamp
        f.update(ring=np.arange(n, dtype=np.uint16) % 32, time=rel.astype(np.float32))
    return driver_cloud(driver, xyz, f, flavor=flavor, stamp_ns=stamp_ns), f


@pytest.mark.parametrize("driver", ["livox", "hesai"])
@pytest.mark.parametrize("flavor", ["rclpy", "rosbags"])
def test_decode_reads_absolute_timestamps_as_offsets_from_the_stamp(driver, flavor):
    xyz = _points(1)
    rel = np.linspace(0.0, 0.1, len(xyz))
    msg, fields = _driver_msg(driver, xyz, rel, flavor=flavor)
    got, times, stamp_ns, _ = decode_cloud(msg, "/lidar", 3)
    np.testing.assert_array_equal(got, xyz)
    assert stamp_ns == STAMP
    # exactly what the recordings' reader makes of the same field (one decoding of ns vs s)
    np.testing.assert_array_equal(times, Scan(0, STAMP, xyz, dict(fields)).point_times())
    np.testing.assert_allclose(times, rel, rtol=0, atol=1e-6)  # float64 absolute times: sub-microsecond
    const, _ = _driver_msg(driver, xyz, np.zeros(len(xyz)), flavor=flavor)
    assert decode_cloud(const, "/lidar", 3)[1] is None  # one time for every point: no per-point timing


def test_input_recognises_its_driver_once_and_preprocesses_with_it():
    calls: list[str | None] = []
    seen: list[tuple[str | None, int]] = []

    def preprocess(xyz, times=None, stamp_ns=None, driver=None):
        calls.append(driver)
        return len(xyz)

    clouds = []
    inp = CloudInput("/livox", PreprocessCache(preprocess), 10, clouds.append, lambda *a: None,
                     on_driver=lambda d, xyz: seen.append((d, len(xyz))))  # fmt: skip
    try:
        for k in range(3):
            xyz = _points(10 + k)
            inp.submit(_driver_msg("livox", xyz, np.linspace(0, 0.1, len(xyz)), STAMP + k * SEC // 10)[0],
                       time.perf_counter())  # fmt: skip
            deadline = time.monotonic() + 5
            while len(clouds) <= k and time.monotonic() < deadline:
                time.sleep(0.005)
        assert seen == [("livox", 400)] and calls == ["livox"] * 3
        assert [c.driver for c in clouds] == ["livox"] * 3 and all(c.times is not None for c in clouds)
    finally:
        inp.stop()


def test_cache_passes_no_driver_to_a_preprocess_without_one():
    got = []
    cache = PreprocessCache(lambda xyz, times=None, stamp_ns=None: got.append(len(xyz)) or 1)
    cache.get(_points(0), "c", driver="livox")  # the GICP anchor's preprocess takes no driver
    assert got == [400]


def test_describe_names_the_driver_and_the_defaults_chosen():
    from deepbbs_ros.config import PreprocessConfig
    from deepbbs_ros.node.drivers import describe

    wide, cfg = _points(0, 2000), PreprocessConfig()  # around the sensor: a spinning sensor's shape
    narrow = wide[np.abs(np.arctan2(wide[:, 1], wide[:, 0])) < np.deg2rad(35)]
    avia = "the livox_avia defaults (preprocess.min_range 1.0, preprocess.voxel_size 0.2, preprocess.ground_search any)"
    assert describe("/l", cfg, "livox", narrow)[0] == f"livox: {avia}"
    line = describe("/l", cfg, "livox", narrow)[1]
    assert line == f"/l: livox driver recognised from the fields; preprocessing with {avia}"
    assert describe("/o", cfg, "ouster", wide)[0] == "ouster: the ouster defaults (the generic ones)"
    assert describe("/v", cfg, "velodyne", narrow)[0] == "velodyne: the generic defaults"  # a crop stays a Velodyne
    assert describe("/p", cfg, None, narrow)[0] == f"none: {avia} (from the cloud's shape)"
    assert describe("/p", cfg, None, wide)[1] == ("/p: no known LiDAR driver in the fields; preprocessing with the "
                                                  "generic defaults (from the cloud's shape)")
    assert describe("/v", cfg, "velodyne", narrow, used=False)[0] == f"velodyne: {avia} (from the cloud's shape)"
    mine = PreprocessConfig(sensor="hdl64", voxel_size=0.25)
    want = "livox: the hdl64 defaults (the generic ones) (preprocess.sensor is 'hdl64')"
    assert describe("/l", mine, "livox", narrow)[0] == want


def test_local_map_odometry_preprocesses_with_its_driver():
    from deepbbs_ros.core.odometry import DeepBBSOdometry

    class Recording:
        def __init__(self):
            self.drivers = []

        def preprocess(self, xyz, times=None, stamp_ns=None, motion=None, *, lazy=False, driver=None):
            self.drivers.append(driver)
            return xyz

    rec = Recording()
    odo = DeepBBSOdometry(Config(), registration=rec)
    odo.register_frame(_points(0, 3000) * 3, None, 0)  # the first scan is prepared for DeepBBS++ at once
    odo.driver = "livox"
    odo.reset()
    odo.register_frame(_points(0, 3000) * 3, None, 0)
    assert rec.drivers == [None, "livox"]


# -- the node over DDS -----------------------------------------------------------------------------------------

class RecordingRegistration:
    """The tiny registration, recording each preprocess's driver and the sensor its result was prepared for."""

    def __init__(self, reg) -> None:
        self.reg, self.device = reg, "cpu"
        self.lock = threading.Lock()
        self.prepared: list[tuple[str | None, str]] = []

    def preprocess(self, xyz, times=None, stamp_ns=None, driver=None):
        res = self.reg.preprocess(xyz, times, stamp_ns, driver=driver)
        with self.lock:
            self.prepared.append((driver, res.sensor))
        return res

    def register(self, source, target, **kw):
        return self.reg.register(source, target, **kw)


def test_node_gives_each_input_its_drivers_defaults(ros, world):
    """Pair mode, a Livox Avia on one input (a 70-degree cone of points) and a Velodyne on the other: the Livox
    scan is preprocessed with the livox_avia defaults, the Velodyne one with the generic defaults as before; both
    named on /diagnostics."""
    cfg = tiny_config(**{"node.diagnostics_period": 0.2})
    rec = RecordingRegistration(tiny_registration(cfg))
    h = Harness(cfg, "reg_drivers", registration=rec)
    try:
        tgt = scan(world, at(10.0), seed=1, n_points=8000)
        src = scan(world, at(10.5), seed=2, n_points=20000)
        src = src[np.abs(np.arctan2(src[:, 1], src[:, 0])) < np.deg2rad(35)]  # the Avia's field of view
        h.send_raw("target_cloud", _driver_msg("velodyne", tgt, np.linspace(0, 0.1, len(tgt)), 5 * SEC)[0])
        h.send_raw("source_cloud", _driver_msg("livox", src, np.linspace(0, 0.1, len(src)), 5 * SEC)[0])
        h.wait_processed(1)
        assert sorted(rec.prepared, key=str) == [("livox", "livox_avia"), ("velodyne", "auto")]
        d = {}
        assert h.wait_for(lambda: d.update(h.diagnostics()) or "input./source_cloud.driver" in d, 5), d
        assert d["input./source_cloud.driver"] == ("livox: the livox_avia defaults (preprocess.min_range 1.0, "
                                                   "preprocess.voxel_size 0.2, preprocess.ground_search any)")
        assert d["input./target_cloud.driver"] == "velodyne: the generic defaults"
    finally:
        h.close()


def test_node_local_map_odometry_consults_deepbbs_with_the_driver(ros, world):
    """Odometry mode (local map): the Livox input's driver reaches DeepBBS++'s preprocessing when the odometry
    consults it (the first motion: the previous and the current scan)."""
    cfg = tiny_config(**{"node.mode": "odometry", "node.base_frame": "", "node.diagnostics_period": 0.2})
    rec = RecordingRegistration(tiny_registration(cfg))
    h = Harness(cfg, "reg_drivers_odom", registration=rec)
    try:
        for k in range(2):
            xyz = scan(world, at(10.0 + 0.3 * k), seed=5 + k, n_points=20000)
            xyz = xyz[np.abs(np.arctan2(xyz[:, 1], xyz[:, 0])) < np.deg2rad(35)]
            h.send_raw("cloud", _driver_msg("livox", xyz, np.linspace(0, 0.1, len(xyz)), (7 + k) * SEC // 10)[0])
            h.wait_processed(k + 1)
        assert h.node.odometry.odometry.driver == "livox"
        assert rec.prepared and all(p == ("livox", "livox_avia") for p in rec.prepared), rec.prepared
        d = {}
        assert h.wait_for(lambda: d.update(h.diagnostics()) or "input./cloud.driver" in d, 5), d
        assert d["input./cloud.driver"].startswith("livox: the livox_avia defaults")
    finally:
        h.close()
