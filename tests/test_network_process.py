"""The network passes in a worker process (core/network_process.py): the same result as in this process, a
real second process, and nothing lost when it dies. Toy world scans (deepbbs_ros.replay.synthetic), a tiny
network saved as a real checkpoint."""

from __future__ import annotations

import logging
import os
import signal
import time

import numpy as np
import pytest
import torch

from deepbbs_ros.config import Config, ModelConfig
from deepbbs_ros.core.checkpoint import save_checkpoint
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network_process import NetworkProcessLost
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.replay.synthetic import synthetic_drive

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)

pytestmark = pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="network_process 'auto' needs 2+ cores")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    torch.manual_seed(0)
    cfg = Config().replace(**{"registration.device": "cpu", "preprocess.num_points": 128, "model.k": 6,
                              "model.dgcnn_widths": [8, 8], "model.emb_dims": 16, "model.n_heads": 2,
                              "model.ff_dims": 16})
    path = save_checkpoint(tmp_path_factory.mktemp("net") / "tiny.pt", DeepBBSNet(TINY), cfg)
    scans = synthetic_drive(frames=4, seed=3)
    return cfg, path, scans


def test_the_network_process_gives_the_in_process_result(setup):
    cfg, path, scans = setup
    here = DeepBBSRegistration(cfg.replace(**{"registration.network_process": "off"}), weights=path)
    away = DeepBBSRegistration(cfg, weights=path)
    try:
        for src, tgt in ((scans[2], scans[0]), (scans[3], scans[1])):
            a = here.register(src.points, tgt.points)
            b = away.register(src.points, tgt.points)
            np.testing.assert_allclose(b.T_target_source, a.T_target_source, atol=1e-9)
            np.testing.assert_allclose(b.gamma, a.gamma, atol=1e-6)
            assert b.iterations == a.iterations and b.polish == a.polish == "ok"
            assert "network_wait" in b.timings_ms and "network_wait" not in a.timings_ms
            assert b.timings_ms["embed"] > 0  # measured in the worker
        pid = away.runner.worker.pid
        assert pid != os.getpid() and away.runner.worker.alive
        # raw scans: the target goes ahead, so the worker prepares its state while the source is preprocessed
        sent = []
        prepare = away.runner.worker.prepare_target
        away.runner.worker.prepare_target = lambda tgt: sent.append(tgt.copy()) or prepare(tgt)
        res = away.register(scans[2].points, scans[0].points)
        assert len(sent) == 1 and np.array_equal(sent[0], res.target)
        np.testing.assert_allclose(res.T_target_source, here.register(scans[2].points, scans[0].points)
                                   .T_target_source, atol=1e-9)
        # an error raised by the passes there comes back as one and leaves the worker running
        bad = np.full((5, 3), np.nan, np.float32)
        with pytest.raises(RegistrationError, match="NaN") as info:
            away.runner.worker.submit(bad, bad, np.eye(4)).result()
        worker = away.runner.worker
        assert not isinstance(info.value, NetworkProcessLost) and worker.alive and worker.pid == pid
        # preprocessed clouds (the node's and the odometry's path) go there too
        pa, pb = here.preprocess(scans[2].points), away.preprocess(scans[0].points)
        np.testing.assert_allclose(away.register(pa, pb).T_target_source, here.register(pa, pb).T_target_source,
                                   atol=1e-9)
    finally:
        away.close()
    assert away.runner.worker is None
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and _running(pid):
        time.sleep(0.05)
    assert not _running(pid)


def test_the_first_call_reports_the_network_process_start_on_its_own(setup):
    """The first register() on a CPU starts the network process (seconds): ``timings_ms["startup"]``, not counted
    in ``"total"`` (the registration's own stages, as on every later call, which has no "startup"); warmup()
    pays it before the first real call."""
    cfg, path, scans = setup
    reg = DeepBBSRegistration(cfg, weights=path)
    try:
        assert reg.runner.state == "unstarted"  # nothing started by the constructor
        t0 = time.perf_counter()
        first = reg.register(scans[2].points, scans[0].points)
        wall_ms = (time.perf_counter() - t0) * 1e3
        assert reg.runner.state == "running"
        t = first.timings_ms
        assert t["startup"] > 0 and t["startup"] + t["total"] <= wall_ms + 1.0, (t, wall_ms)
        stages = ("preprocess", "embed", "match", "solve", "refine", "network_wait", "polish", "deskew", "global")
        own = sum(t.get(k, 0.0) for k in stages if k not in ("embed", "match", "solve"))  # those ran in the worker
        assert t["total"] == pytest.approx(own, abs=1e-6)
        assert t["total"] < wall_ms - t["startup"] + 1.0
        second = reg.register(scans[3].points, scans[1].points)
        assert "startup" not in second.timings_ms
    finally:
        reg.close()
    reg = DeepBBSRegistration(cfg, weights=path)
    try:
        reg.warmup(rounds=1)
        assert reg.runner.state == "running"
        assert "startup" not in reg.register(scans[2].points, scans[0].points).timings_ms
    finally:
        reg.close()
    here = DeepBBSRegistration(cfg.replace(**{"registration.network_process": "off"}), weights=path)
    assert "startup" not in here.register(scans[2].points, scans[0].points).timings_ms  # nothing to start


def test_a_dead_network_process_loses_nothing(setup, caplog):
    """The worker killed between two registrations: the next one runs the network here, logs it once, and
    gives the same result; so does a model object (never a worker: its weights may change, as in training)."""
    cfg, path, scans = setup
    reg = DeepBBSRegistration(cfg, weights=path)
    ref = reg.register(scans[2].points, scans[0].points).T_target_source
    os.kill(reg.runner.worker.pid, signal.SIGKILL)
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and reg.runner.worker.alive:
        time.sleep(0.05)
    with caplog.at_level(logging.WARNING, logger="deepbbs_ros.core.registration"):
        res = reg.register(scans[2].points, scans[0].points)
        reg.register(scans[3].points, scans[1].points)
    np.testing.assert_allclose(res.T_target_source, ref, atol=1e-9)
    assert "network_wait" not in res.timings_ms and reg.runner.worker is None
    warnings = [r for r in caplog.records if "network in this process" in r.getMessage()]
    assert len(warnings) == 1 and "died" in warnings[0].getMessage()
    own = DeepBBSRegistration(cfg, model=reg.model)
    own.register(scans[2].points, scans[0].points)
    assert own.runner.worker is None and own.runner.state == "off"


def test_a_stage_that_raises_while_the_network_process_works_leaves_it_usable(setup, monkeypatch):
    """The precision clouds fail while the worker holds an answer: the answer is read and dropped, and the next
    registration gets its own."""
    cfg, path, scans = setup
    reg = DeepBBSRegistration(cfg, weights=path)
    try:
        ref = reg.register(scans[3].points, scans[1].points).T_target_source

        def broken(st, clock):
            raise RegistrationError("small_gicp failed")

        monkeypatch.setattr(reg, "_precision_clouds", broken)
        with pytest.raises(RegistrationError, match="small_gicp failed"):
            reg.register(scans[2].points, scans[0].points)
        monkeypatch.undo()
        res = reg.register(scans[3].points, scans[1].points)
        np.testing.assert_allclose(res.T_target_source, ref, atol=1e-9)
        assert "network_wait" in res.timings_ms and reg.runner.worker.alive
    finally:
        reg.close()


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is gone for our purpose
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def test_node_inputs_leave_the_covariances_to_register(setup):
    # the node's inputs preprocess on arrival with the precision stage's k-d tree and covariances deferred:
    # register() builds them while the network process runs the passes, with the same result
    from deepbbs_ros.node.preprocess_cache import arrival_preprocess

    cfg, path, scans = setup
    here = DeepBBSRegistration(cfg.replace(**{"registration.network_process": "off"}), weights=path)
    away = DeepBBSRegistration(cfg, weights=path)
    try:
        assert away.defers_precision and not here.defers_precision
        assert "defer" not in getattr(arrival_preprocess(here), "keywords", {})  # no network process: built on arrival
        src, tgt = (arrival_preprocess(away)(s.points) for s in (scans[2], scans[0]))
        assert src.polish_cloud.pending is not None and src.polish_cloud.tree is None
        full = here.register(here.preprocess(scans[2].points), here.preprocess(scans[0].points))
        res = away.register(src, tgt)
        assert src.polish_cloud.pending is None and tgt.polish_cloud.pending is None  # completed in place, once
        np.testing.assert_allclose(res.T_target_source, full.T_target_source, atol=1e-9)
        assert res.polish == "ok" and res.timings_ms["preprocess"] > 0
        again = away.register(src, tgt)  # the cached clouds serve again as they are
        np.testing.assert_allclose(again.T_target_source, full.T_target_source, atol=1e-9)
        # small_gicp threads: every core while the worker is idle, one fewer while it computes
        assert not away.runner.worker.working and away.gicp_threads() == os.cpu_count()
        fixed = DeepBBSRegistration(cfg.replace(**{"registration.polish_threads": 1}), weights=path)
        assert fixed.gicp_threads() == 1
    finally:
        away.close()
