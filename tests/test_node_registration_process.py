"""The pair-mode node's registration in a process of its own (``node.registration_process``,
node/registration_process.py), with the shipped weights, real processes, real rclpy and DDS.

* the proxy gives the in-process registration's answer on the toy street (tests/conftest.py), turns the
  worker's bad-input error into a RegistrationError with its message, and keeps a bounded number of scans
  (the node's dropped handles are released there);
* the node in pair mode answers toy-street pairs through it with the right pose, rejects a cloud the worker
  cannot preprocess with its one-line error, and when the worker is killed mid-run says so in one line and
  goes on answering in its own process.
"""

from __future__ import annotations

import functools
import gc
import os
import signal
import time

import numpy as np
import pytest

from deepbbs_ros.node.dds import apply_default_profile

apply_default_profile()
rclpy = pytest.importorskip("rclpy")


from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.errors import RegistrationError  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from msg_adapters.pointcloud2 import arrays_to_pointcloud2  # noqa: E402
from msg_adapters.transforms import pose_stamped_to_matrix  # noqa: E402


def _shipped_weights_exist() -> bool:
    from deepbbs_ros.core.checkpoint import default_weights_path

    return default_weights_path().is_file()


pytestmark = pytest.mark.skipif(not _shipped_weights_exist(), reason="shipped weights missing")

SEC = 1_000_000_000
NAME = "deepbbs_regproc"
# the toy street seen from a sensor 1.9 m above the road, the source turned 10 deg and moved 1.1 m
MOTION = ((10.0, 0.0, 0.0), (1.0, 0.5, 0.0))


def _config(**extra) -> Config:
    return Config().replace(**{"registration.device": "cpu", "registration.threads": 1, "node.warmup": False,
                               "node.registration_process": "on", **extra})


def _pair(street_pair, seed: int):
    src, tgt, T = street_pair(seed, 20000, *MOTION, road=True)
    return np.concatenate(src), np.concatenate(tgt), T


@pytest.fixture(scope="module")
def proxy():
    from deepbbs_ros.core.checkpoint import default_weights_path
    from deepbbs_ros.node.parameters import node_registration_config
    from deepbbs_ros.node.registration_process import RegistrationProcess

    rp = RegistrationProcess(node_registration_config(_config()), default_weights_path())
    yield rp
    rp.close()
    assert rp._proc.poll() is not None and rp.network_process_state.startswith("stopped")


def test_proxy_gives_the_in_process_answer(proxy, street_pair):
    from deepbbs_ros.core.registration import DeepBBSRegistration

    src, tgt, T_gt = _pair(street_pair, 0)
    h_src, h_tgt = proxy.preprocess(src, defer=True), proxy.preprocess(tgt, defer=True)
    assert h_src.points.shape == (512, 3) and h_src.timings_ms["total"] > 0
    res = proxy.register(h_src, h_tgt)
    rot, trans = pair_errors(res.T_target_source, T_gt)
    assert rot < 0.5 and trans < 0.05 and res.valid, (rot, trans)
    assert res.timings_ms["transfer"] >= 0 and "polish" in res.timings_ms
    local = DeepBBSRegistration(proxy.config, weights=proxy.weights)
    try:
        ref = local.register(src, tgt)
    finally:
        local.close()
    np.testing.assert_allclose(res.T_target_source, ref.T_target_source, atol=1e-6)
    assert proxy.network_process_state.startswith("running (pid ")  # the worker's own network process


def test_proxy_good_start_leaves_the_sampling_to_the_worker(proxy, street_pair):
    """Handles preprocessed lazily (the node's inputs) carry no sampled points; a good start answers on the GICP path
    in the worker, a start 3.5 m off too (GICP from it comes back, beyond the good start's limits, and the verdict
    takes it: core/good_start.py), a start turned 30 degrees (GICP settles on a pose the verdict rejects, the truth is
    beyond the coarse try's reach: core/coarse_rescue.py) falls back there (sampling there), all right."""
    from deepbbs_ros.replay.synthetic import pose

    src, tgt, T_gt = _pair(street_pair, 2)
    h_src, h_tgt = proxy.preprocess(src, defer=True, lazy=True), proxy.preprocess(tgt, defer=True, lazy=True)
    assert h_src.points is None and h_tgt.points is None
    res = proxy.register(h_src, h_tgt, T_init=T_gt, good_start=True)
    assert res.path == "gicp" and res.valid and max(pair_errors(res.T_target_source, T_gt)) < 0.3
    off = T_gt.copy()
    off[:3, 3] += (0.0, 3.5, 0.0)  # across the street: GICP moves it further than good_start_max_trans allows
    res = proxy.register(h_src, h_tgt, T_init=off, good_start=True)
    taken = ("accepted after coarse to fine (GICP from the start: moved",
             "accepted, beyond the good start's limits (GICP from the start: moved")
    assert res.path == "gicp" and res.good_start.startswith(taken), res.good_start
    assert res.valid and max(pair_errors(res.T_target_source, T_gt)) < 0.3
    res = proxy.register(h_src, h_tgt, T_init=T_gt @ pose(0.0, 0.0, 0.0, np.radians(30.0)), good_start=True)
    assert res.path in ("deepbbs", "search") and not res.good_start.startswith("accepted"), res
    assert not res.valid or max(pair_errors(res.T_target_source, T_gt)) < 0.5


def test_proxy_bad_input_is_one_line(proxy):
    with pytest.raises(RegistrationError, match=r"shape \(5, 4\)"):
        proxy.preprocess(np.zeros((5, 4), np.float32))
    far = np.full((500, 3), 500.0, np.float32)  # every point beyond preprocess.max_range
    with pytest.raises(RegistrationError, match="within"):
        proxy.preprocess(far)
    assert proxy.alive


def test_proxy_preprocesses_with_the_driver(proxy, street_pair):
    """The driver the node recognised reaches the preprocessing for the worker; the handle keeps it."""
    src, _, _ = _pair(street_pair, 3)
    cone = src[np.abs(np.arctan2(src[:, 1], src[:, 0])) < np.deg2rad(35)]  # a Livox Avia's field of view
    h = proxy.preprocess(cone, defer=True, lazy=True, driver="livox")
    assert (h.driver, h.sensor) == ("livox", "livox_avia")
    assert proxy.preprocess(src, defer=True, lazy=True, driver="velodyne").sensor == "auto"  # the generic defaults


def test_proxy_handles_are_released(proxy, street_pair):
    from deepbbs_ros.node.registration_process import MAX_SCANS

    src, tgt, T_gt = _pair(street_pair, 1)
    handles = [proxy.preprocess(src if k % 2 else tgt) for k in range(MAX_SCANS + 4)]
    assert proxy.kept() == MAX_SCANS  # bounded: the oldest are forgotten ...
    first = handles[1].id
    res = proxy.register(handles[1], handles[0])  # ... and sent again when the node still registers them
    assert handles[1].id != first and max(pair_errors(res.T_target_source, T_gt)) < 0.5
    assert proxy.kept() == MAX_SCANS
    del handles, res
    gc.collect()
    assert proxy.kept() == 0  # the handles the node dropped are released with its next request


@pytest.fixture(scope="module")
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_node_answers_through_the_registration_process_and_survives_its_death(ros, street_pair, pair_client):
    from deepbbs_ros.node.registration_node import RegistrationNode
    from deepbbs_ros.node.registration_process import RegistrationProcess

    node = RegistrationNode(_config(), node_name=NAME)
    assert isinstance(node.reg, RegistrationProcess) and node.reg.alive
    logs: list[str] = []
    node.reg._log = logs.append  # the node's error log: captured to count the lines
    client, poses, pubs, executor = pair_client(node, NAME)

    def send(src, tgt, stamp):
        pubs["target_cloud"].publish(arrays_to_pointcloud2(tgt, stamp_ns=stamp, frame_id="lidar"))
        pubs["source_cloud"].publish(arrays_to_pointcloud2(src, stamp_ns=stamp, frame_id="lidar"))

    def wait_for(cond, timeout=90.0, again=None):
        """Wait for ``cond``; ``again`` every 10 s meanwhile (a best-effort cloud lost on a busy machine is sent
        again: the synchroniser refuses a stamp it already paired, the cache preprocesses it once)."""
        deadline = time.monotonic() + timeout
        next_try = time.monotonic() + 10.0
        while time.monotonic() < deadline and not cond():
            time.sleep(0.02)
            if again is not None and time.monotonic() > next_try:
                again()
                next_try = time.monotonic() + 10.0
        return cond()

    try:
        assert wait_for(lambda: all(p.get_subscription_count() for p in pubs.values()), 10)
        pairs = [_pair(street_pair, seed) for seed in (2, 3, 4, 5)]
        kill_after = 2
        for k, (src, tgt, T_gt) in enumerate(pairs):
            if k == kill_after:  # the worker dies mid-run: one line, the node registers itself from then on
                os.kill(node.reg.pid, signal.SIGKILL)
                assert wait_for(lambda: node.reg._proc.poll() is not None, 10)
            stamp = (10 + k) * SEC
            send(src, tgt, stamp)
            assert wait_for(lambda k=k: len(poses) > k, again=functools.partial(send, src, tgt, stamp)), node.stats()
            T, stamp_out, frame = pose_stamped_to_matrix(poses[k])
            rot, trans = pair_errors(T, T_gt)
            assert (stamp_out, frame) == (stamp, "lidar")
            assert rot < 0.5 and trans < 0.05, (k, rot, trans)
            if k == 0:  # a cloud the worker cannot preprocess: its one-line error, nothing published
                far = np.full((500, 3), 500.0, np.float32)
                bad = (10 + k) * SEC + SEC // 2
                send(far, pairs[1][1], bad)
                assert wait_for(lambda: node.stats()["errors"].get("preprocess_failed", 0) >= 1, 60,
                                again=functools.partial(send, far, pairs[1][1], bad)), node.stats()
        assert len(logs) == 1 and "registering in the node's process" in logs[0], logs
        # (the client may see the last pose before the node has counted it)
        assert wait_for(lambda: node.stats()["published"] == len(pairs), 10), node.stats()
        assert node.reg.state.startswith("failed")
        errors = node.stats()["errors"]
        assert set(errors) == {"preprocess_failed"}, errors  # (sent again only if lost: the same cloud's error)
    finally:
        executor.shutdown()
        node.destroy_node()
        client.destroy_node()
    assert node.reg._local is not None  # the fallback's registration, whose network process destroy_node stopped:
    assert not node.reg.network_process_state.startswith("running"), node.reg.network_process_state
