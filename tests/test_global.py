"""The verdict and the global search: a pose from any start, and whether it can be trusted.

Shipped weights, default configuration, raw simulated HDL-64E scans (deepbbs_ros.sim): frames 0 and 5 of an
urban drive are a true pair; frame 0 of a highway drive of another seed is a different place.
"""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import global_search, verdict
from deepbbs_ros.core.checkpoint import default_weights_path
from deepbbs_ros.metrics import pair_errors
from deepbbs_ros.replay.synthetic import pose


def test_fitness_and_decision():
    import small_gicp

    rng = np.random.default_rng(0)
    tgt = rng.uniform(-20, 20, (4000, 3))
    tree = small_gicp.KdTree(small_gicp.PointCloud(tgt))
    src = tgt[:500] + rng.normal(0, 0.05, (500, 3))
    assert verdict.fitness(src, tree, np.eye(4), 0.5) > 0.95
    assert verdict.fitness(src, tree, pose(0, 0, 0, np.radians(40.0)), 0.5) < 0.3
    assert verdict.fitness_to_points(src, tgt, np.eye(4), 0.5) == pytest.approx(verdict.fitness(src, tree, np.eye(4),
                                                                                                 0.5))
    assert verdict.fitness(np.zeros((0, 3)), tree, np.eye(4), 0.5) == 0.0
    assert verdict.is_valid(0.3, 0.3) and not verdict.is_valid(0.29, 0.3) and not verdict.is_valid(float("nan"), 0)


def test_yaw_starts_cover_the_circle():
    T0 = pose(1.0, 2.0, 0.0, np.radians(10.0))
    starts = global_search.yaw_starts(T0, 4)
    assert len(starts) == 3
    for k, T in enumerate(starts, 1):
        rel = np.linalg.inv(T0) @ T
        assert np.allclose(rel[:3, 3], 0) and np.degrees(np.arctan2(rel[1, 0], rel[0, 0])) == pytest.approx(
            [90, 180, -90][k - 1])
    ranked = global_search.rank_outputs([("out", T) for T in starts], lambda T: -abs(T[0, 3] - 1.0) - T[1, 0])
    assert [r[0] for r in ranked] == sorted([r[0] for r in ranked], reverse=True)


def test_batched_starts_equal_single_passes(street_pair):
    """K starts through the network as one batch (the target's state computed once and broadcast) give each
    start's single-pass answer: R, t, gamma to round-off, the same passes run (a start whose increment is small
    leaves the batch as a single run stops)."""
    import torch

    from deepbbs_ros.config import ModelConfig
    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.core.network import DeepBBSNetwork

    # in float64: float32 batched and single matrix products round differently on some CPUs (a batch's GEMM
    # blocking; 1e-5..2e-4 after four passes through the sharp soft maps on an AVX-512 Xeon), which would hide
    # what this test checks, the batch's bookkeeping; in float64 the two agree to 1e-13
    torch.manual_seed(0)
    model = DeepBBSNet(ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)).eval().double()
    cfg = Config().replace(**{"registration.max_deep_iters": 4, "registration.deep_rot_tol_deg": 2.0,
                              "registration.deep_trans_tol": 0.3})
    net = DeepBBSNetwork(cfg, model=model, device="cpu")
    src, tgt, _ = street_pair(3, 300, [20.0, 0.0, 0.0], [1.0, -0.5, 0.0])
    starts = [np.eye(4)] + global_search.yaw_starts(pose(0.5, 0.0, 0.0, 0.1), 4)
    T = np.stack(starts)
    with torch.inference_mode():
        s, t = net.scaled(src.astype(np.float64)), net.scaled(tgt.astype(np.float64))
        R0 = torch.as_tensor(T[:, :3, :3], dtype=torch.float64)
        t0 = torch.as_tensor(T[:, :3, 3] * net.model.scale, dtype=torch.float64)
        batch = net.starts(s, t, R0, t0)
        single = [net.passes(s, t, R0[i], t0[i], lambda _stage: None) for i in range(len(starts))]
    assert len(batch) == len(starts)
    for b, one in zip(batch, single):
        np.testing.assert_allclose(b.R, one.R, atol=1e-9)
        np.testing.assert_allclose(b.t / net.model.scale, one.t / net.model.scale, atol=1e-9)
        np.testing.assert_allclose(b.gamma, one.gamma, atol=1e-9)
        assert (b.iterations, b.converged) == (one.iterations, one.converged)
        assert b.temperature == pytest.approx(one.temperature, abs=1e-9)
    assert len({one.iterations for one in single}) > 1  # some starts left the batch early: that path is checked


def test_ranking_prefix():
    """The search's ranking passes see the first ``registration.global_rank_points`` of both clouds (all of
    them at 0 or when the clouds are smaller); a ranking output's gamma is padded with zeros to the full cloud."""
    from deepbbs_ros.core.network import NetworkOutput
    from deepbbs_ros.errors import ConfigError

    rc = Config().registration
    assert global_search.rank_size(rc, 512) == 256 and global_search.rank_size(rc, 200) == 200
    assert global_search.rank_size(Config().replace(**{"registration.global_rank_points": 0}).registration, 512) == 512
    with pytest.raises(ConfigError, match="global_rank_points"):
        Config().replace(**{"registration.global_rank_points": 8})
    out = NetworkOutput(np.eye(3, dtype=np.float32), np.zeros(3, np.float32), np.ones(256, np.float32), 1.0, 1, True)
    full = global_search.full_gamma(out, 512)
    assert full.gamma.shape == (512,) and full.gamma[:256].all() and not full.gamma[256:].any()
    assert global_search.full_gamma(full, 512) is full


def test_speculative_starts_in_the_network_process(tmp_path, street_pair):
    """The network process runs the other start yaws after the given start's passes: cancelled, nothing of it
    reaches the next request; read, it is what the caller would compute from the same starts on the clouds' first
    ``registration.global_rank_points`` (the ranking passes' farthest-point prefix)."""
    import torch

    from deepbbs_ros.config import ModelConfig
    from deepbbs_ros.core.checkpoint import save_checkpoint
    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.core.network import DeepBBSNetwork
    from deepbbs_ros.core.network_process import NetworkProcess

    torch.manual_seed(0)
    cfg = Config()
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16,
                                                                     n_heads=2, ff_dims=16)), cfg)
    src, tgt, _ = street_pair(4, 300, [30.0, 0.0, 0.0], [0.5, 0.0, 0.0])
    here = DeepBBSNetwork(cfg, weights=path, device="cpu")
    others = np.stack(global_search.yaw_starts(np.eye(4), 4))
    proc = NetworkProcess(path, cfg.to_flat())
    try:
        first = proc.submit(src, tgt, np.eye(4), speculate=others)
        out = first.result()
        outs = first.result()  # all of them: nobody stopped it
        assert len(outs) == 3
        want = here.network_np(src, tgt, np.eye(4))
        np.testing.assert_allclose(out.R, want.R, atol=1e-5)
        k = global_search.rank_size(cfg.registration, len(src))
        assert k == 256 < len(src)  # the default: a prefix of the 300 points
        for T0, o in zip(others, outs):
            R, t = here.start_tensors(T0)
            with torch.inference_mode(), here.torch_threads():  # on registration.threads, as the process computes
                one = here.passes(here.scaled(src[:k]), here.scaled(tgt[:k]), R, t, lambda _stage: None, n_passes=1)
            np.testing.assert_allclose(o.R, one.R, atol=1e-5)
            assert o.gamma.shape == (k,)
        cancelled = proc.submit(src, tgt, np.eye(4), speculate=others)
        cancelled.result()
        cancelled.cancel()  # not wanted: stopped, read before the next request
        again = proc.submit(src, tgt, np.eye(4)).result()
        np.testing.assert_allclose(again.R, want.R, atol=1e-5)
        assert not proc.working
    finally:
        proc.close()


@pytest.fixture(scope="module")
def scans():
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    from deepbbs_ros.sim.simulator import DriveSimulator

    urban = DriveSimulator("urban", 5, frames=60)
    other = DriveSimulator("highway", 11, frames=2)
    T_gt = np.linalg.inv(urban.pose_at(0)) @ urban.pose_at(30)
    return urban.scan_at(30).points, urban.scan_at(0).points, T_gt, other.scan_at(0).points


@pytest.fixture(scope="module")
def registrations():
    from deepbbs_ros.core.registration import DeepBBSRegistration

    cfg = Config().replace(**{"registration.network_process": "off"})
    regs = {"auto": DeepBBSRegistration(cfg), "off": DeepBBSRegistration(cfg.replace(
        **{"registration.global_search": "off"}))}
    yield regs
    for r in regs.values():
        r.close()


def test_any_start_and_the_verdict(scans, registrations):
    src, tgt, T_gt, elsewhere = scans
    P = pose(3.0, -6.0, 0.0, np.radians(150.0))  # the source turned by 150 degrees and moved 6.7 m
    moved = (src @ P[:3, :3].T + P[:3, 3]).astype(np.float32)
    good = registrations["auto"].register(src, tgt)  # a good start: the search does not run
    assert good.valid and good.starts == 1 and good.probability >= Config().registration.verdict_probability
    assert good.path == "deepbbs" and good.good_start == ""  # the deep passes from the given start answered
    assert max(pair_errors(good.T_target_source, T_gt)) < 0.3
    res = registrations["auto"].register(moved, tgt)  # no initial guess: the global search finds it
    rot, tr = pair_errors(res.T_target_source @ P, T_gt)
    assert rot < 1.0 and tr < 0.3, (rot, tr)
    assert res.valid and res.starts == 4 and res.path == "search"
    local = registrations["off"].register(moved, tgt)  # from the given start only: a wrong pose, rejected
    assert max(pair_errors(local.T_target_source @ P, T_gt)) > 1.0
    assert not local.valid and local.probability < res.probability
    lost = registrations["auto"].register(elsewhere, tgt)  # another place: a pose, but not a valid one
    assert not lost.valid and lost.starts == 4 + 17  # the yaw starts, then the turned and shifted ones: none valid
    # the search switched off for one call (callers sharing a registration on several threads): the configuration
    # is not touched, and the next call searches again
    once = registrations["auto"].register(moved, tgt, yaw_search=False)
    assert once.starts == 1 and not once.valid
    assert np.allclose(once.T_target_source, local.T_target_source, atol=1e-4)  # as with global_search "off"
    assert registrations["auto"].config.registration.global_search == "auto"
    again = registrations["auto"].register(moved, tgt)
    assert again.valid and again.starts == 4


def test_odometry_recovers_a_kidnapped_sensor():
    """Mid-drive the sensor is turned by 130 degrees and moved 2.2 m at once (a kidnapped robot): the map fit
    collapses, DeepBBS++ (its global search) registers the scan against the previous one, the jump is reported
    (``deepbbs``, ``won``, the fit drop as ``reason``) and the track goes on within 1 deg / 0.3 m."""
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    from deepbbs_ros.core.odometry import DeepBBSOdometry
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("urban", 5, frames=30, compensate=True)
    J = pose(2.0, -1.0, 0.0, np.radians(130.0))
    odo = DeepBBSOdometry(Config().replace(**{"registration.network_process": "off"}))
    P0, steps = sim.pose_at(10), []
    for k in range(10, 19):
        pts, Pk = sim.scan_at(k).points, sim.pose_at(k)
        if k >= 15:  # the sensor at Pk @ J sees p' = J^-1 p
            pts, Pk = ((pts - J[:3, 3]) @ J[:3, :3]).astype(np.float32), Pk @ J
        out = odo.register_frame(pts)
        steps.append(out)
        rot, tr = pair_errors(out.T_first_k, np.linalg.inv(P0) @ Pk)
        assert rot < 1.0 and tr < 0.3, (k, rot, tr, out.reason)
    jump = steps[5]
    assert jump.deepbbs and jump.won and jump.reason.startswith("fit")
    assert jump.path in ("deepbbs", "search") and steps[0].path == ""  # DeepBBS++'s answer kept; the origin
    assert all(s.path == "gicp" for s in steps[1:] if not s.won)  # GICP against the map answered
    assert pair_errors(jump.T_prev_k, np.linalg.inv(sim.pose_at(14)) @ sim.pose_at(15) @ J)[0] < 1.0
