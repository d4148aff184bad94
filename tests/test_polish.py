"""The GICP precision stage after DeepBBS++ (registration.polish, core/polish.py) and its config."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from deepbbs_ros.config import Config, ModelConfig
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.polish import PolishCloud, polish, prepare_polish_cloud
from deepbbs_ros.core.preprocess import PreprocessResult, dense_subsample, farthest_point_sample, voxel_downsample
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.errors import ConfigError

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)


def _prep(non_ground: np.ndarray, ground: np.ndarray, seed: int) -> PreprocessResult:
    """The pipeline's outputs: 1000 FPS points, dense voxels, and the whole scan (ground kept) prepared
    for the precision stage."""
    v = voxel_downsample(non_ground, 0.3)
    return PreprocessResult(v[farthest_point_sample(v, 1000, seed=1)], None, 0, 0, 0,
                            dense_points=dense_subsample(v, 3000, seed=seed),
                            polish_cloud=prepare_polish_cloud(np.concatenate([non_ground, ground]), 0.5, 20))


@pytest.fixture(scope="module")
def pair(street_pair):
    """Two independent noisy samplings of the street with its road; the source seen from T_target_source."""
    src, tgt, T = street_pair(7, 40000, [4.0, 0.3, -0.2], [1.2, 0.3, 0.03], road=True)
    return _prep(*src, seed=1), _prep(*tgt, seed=2), T


def _offset(trans=(0.4, -0.3, 0.0), yaw_deg=1.0) -> np.ndarray:
    """A DeepBBS-like error: 0.5 m along/across the road, 1 deg of yaw."""
    D = np.eye(4)
    D[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    D[:3, 3] = trans
    return D


def _err(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    E = np.linalg.inv(T_gt) @ T_est
    return float(np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))), float(np.linalg.norm(E[:3, 3]))


def _cfg(**flat):
    return Config().replace(**{"registration.polish": "gicp", **flat}).registration


def _clouds(res: PreprocessResult) -> PolishCloud:
    return res.polish_cloud


def _unpolished(src: PreprocessResult, tgt: PreprocessResult, T0: np.ndarray):
    """A tiny seeded random network (deep stage off, refinement from ``T0``), registered without the polish.

    Returns ``(config, model, result)`` so the polished run can reuse the same config and weights.
    """
    torch.manual_seed(0)
    base = Config().replace(**{"registration.device": "cpu", "registration.deep": False, "registration.threads": 1,
                               "registration.refine": True, "registration.polish": "none"})
    model = DeepBBSNet(TINY).eval()
    return base, model, DeepBBSRegistration(base, model=model).register(src, tgt, T_init=T0)


@pytest.mark.parametrize("method", ["gicp", "plane_icp"])
def test_polish_recovers_the_transform_from_a_deepbbs_like_estimate(pair, method):
    src, tgt, T = pair
    T0 = T @ _offset()
    assert _err(T0, T)[1] > 0.4
    res = polish(_clouds(src), _clouds(tgt), T0, _cfg(**{"registration.polish": method}))
    rot, trans = _err(res.T_target_source, T)
    assert res.applied and res.reason == "ok" and res.converged, res
    assert trans < 0.03 and rot < 0.1, (rot, trans)
    assert 1 <= res.iterations <= 20 and res.num_inliers > 100
    assert res.delta_trans_m == pytest.approx(np.linalg.norm(res.T_target_source[:3, 3] - T0[:3, 3]))
    assert set(res.timings_ms) == {"prepare", "align", "total"}


def test_register_runs_the_polish_stage(pair):
    """register() with a tiny random network (deep stage off, refinement from T_init) + the polish."""
    src, tgt, T = pair
    T0 = T @ _offset()
    base, model, plain = _unpolished(src, tgt, T0)
    pol = DeepBBSRegistration(base.replace(**{"registration.polish": "gicp"}), model=model)
    res = pol.register(src, tgt, T_init=T0)
    rot, trans = _err(res.T_target_source, T)
    assert trans < 0.03 and rot < 0.1, (rot, trans, _err(plain.T_target_source, T))
    assert res.polish == "ok" and res.iterations["polish"] >= 1 and plain.iterations["polish"] == 0
    assert "polish" in res.timings_ms and "polish" not in plain.timings_ms and plain.polish == ""
    assert res.timings_ms["total"] == pytest.approx(sum(v for k, v in res.timings_ms.items() if k != "total"))
    assert res.inlier_ratio > 0.9
    # plain arrays carry no dense scan: the polish cannot run and is skipped
    arr = pol.register(src.points, tgt.points, T_init=T0, preprocessed=True)
    assert arr.polish == "" and arr.iterations["polish"] == 0


@pytest.mark.parametrize(
    "flat, reason",
    [
        ({"registration.polish_max_corr_dist": 1e-4}, "not converged|correspondences"),
        ({"registration.polish_max_trans": 0.05}, "moved .* > polish_max_trans"),
        ({"registration.polish_max_rot_deg": 0.05}, "turned .* > polish_max_rot_deg"),
    ],
)
def test_polish_falls_back_to_the_deepbbs_estimate(pair, flat, reason):
    src, tgt, T = pair
    T0 = T @ _offset()
    res = polish(_clouds(src), _clouds(tgt), T0, _cfg(**flat))
    assert not res.applied
    assert re.search(reason, res.reason), res.reason
    np.testing.assert_array_equal(res.T_target_source, T0)


def test_register_keeps_the_estimate_when_the_polish_is_rejected(pair):
    src, tgt, T = pair
    T0 = T @ _offset()
    base, model, plain = _unpolished(src, tgt, T0)
    cfg = base.replace(**{"registration.polish": "gicp", "registration.polish_max_trans": 0.01})
    res = DeepBBSRegistration(cfg, model=model).register(src, tgt, T_init=T0)
    assert res.polish.startswith("moved") and res.iterations["polish"] >= 1
    np.testing.assert_allclose(res.T_target_source, plain.T_target_source, atol=1e-9)
    assert res.inlier_ratio == plain.inlier_ratio and res.converged == plain.converged


def test_too_few_points_fall_back(pair):
    src, tgt, T = pair
    res = polish(src.dense_points[:5], tgt.polish_cloud, T, _cfg())
    assert not res.applied and re.match(r"only [0-5] points after the voxel grid", res.reason), res.reason
    np.testing.assert_array_equal(res.T_target_source, T)


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("registration.polish", "ndt", "registration.polish must be 'none', 'gicp' or 'plane_icp'"),
        ("registration.polish_voxel", -0.1, "registration.polish_voxel must be >= 0"),
        ("registration.polish_max_corr_dist", 0.0, "registration.polish_max_corr_dist must be > 0"),
        ("registration.polish_max_iters", 0, "registration.polish_max_iters must be >= 1"),
        ("registration.polish_neighbors", 3, "registration.polish_neighbors must be >= 5"),
        ("registration.polish_max_trans", -1.0, "registration.polish_max_trans must be >= 0"),
        ("registration.polish_max_rot_deg", -1.0, "registration.polish_max_rot_deg must be >= 0"),
        ("registration.polish_threads", -1, "registration.polish_threads must be >= 0"),
        ("registration.polish_rot_eps_deg", 0.0, "registration.polish_rot_eps_deg must be > 0"),
        ("registration.polish_trans_eps", -1e-3, "registration.polish_trans_eps must be > 0"),
        ("registration.polish_max_voxels", -1, "registration.polish_max_voxels must be >= 0"),
    ],
)
def test_config_validation(key, value, match):
    with pytest.raises(ConfigError, match=match):
        Config().replace(**{key: value}).validate()


def test_precision_stage_is_on_by_default_and_in_the_shipped_param_file():
    from pathlib import Path

    assert Config().registration.polish == "gicp"
    cfg = Config.from_yaml(Path(__file__).resolve().parents[1] / "config" / "deepbbs_ros.yaml")
    assert cfg.registration.polish == Config().registration.polish
    assert cfg.registration.polish_max_trans == Config().registration.polish_max_trans


def test_replay_method_deepbbs_pp_gicp(pair, street_scene):
    """``deepbbs++gicp`` in replay: parsed, a ROS-legal topic name, prepare keeps the precision-stage cloud."""
    from deepbbs_ros.replay.methods import build_methods, parse_methods, topic_name

    assert parse_methods("deepbbs++,deepbbs++gicp,gicp", "pairs") == ["deepbbs++", "deepbbs++gicp", "gicp"]
    assert topic_name("deepbbs++gicp") == "deepbbs_pp_gicp" and topic_name("deepbbs++") == "deepbbs_pp"
    rng = np.random.default_rng(3)
    T = pair[2]
    tgt = np.concatenate(street_scene(rng, 40000, road=True))
    src = (np.concatenate(street_scene(rng, 40000, road=True)) - T[:3, 3]) @ T[:3, :3]
    torch.manual_seed(0)
    cfg = Config().replace(**{"registration.device": "cpu", "registration.deep": False, "registration.threads": 1,
                              "registration.refine": True})
    methods = build_methods(["deepbbs++", "deepbbs++gicp"], cfg, model=DeepBBSNet(TINY).eval())
    assert methods["deepbbs++gicp"].reg.model is methods["deepbbs++"].reg.model  # one network
    m = methods["deepbbs++gicp"]
    p_src, _ = m.prepare(src.astype(np.float32))
    p_tgt, _ = m.prepare(tgt.astype(np.float32))
    assert isinstance(p_src, PreprocessResult) and p_src.polish_cloud is not None and p_src.polish_cloud.n_points > 100
    T_est, info, ms = m.align(p_src, p_tgt, T @ _offset())
    assert info["polish"] == "ok" and info["polish_ms"] > 0 and ms > 0
    rot, trans = _err(T_est, T)
    assert trans < 0.05 and rot < 0.15, (rot, trans)
    assert isinstance(methods["deepbbs++"].prepare(src.astype(np.float32))[0], PreprocessResult)


def test_precision_stage_lands_on_gicps_fixed_point(pair, street_scene):
    """Started inside the basin, the precision stage returns what the small_gicp GICP baseline returns
    from the truth: the same clouds, the same settings, so the same optimum (issue 11)."""
    from deepbbs_ros.baselines import SmallGicpRegistration
    from deepbbs_ros.replay.runner import offline_threads

    rng = np.random.default_rng(5)
    T = pair[2]
    tgt = np.concatenate(street_scene(rng, 40000, road=True)).astype(np.float32)
    src = ((np.concatenate(street_scene(rng, 40000, road=True)) - T[:3, 3]) @ T[:3, :3]).astype(np.float32)
    # the same threads too, as in a replay (offline_threads): small_gicp's voxel grid on several threads splits the
    # voxels that straddle its blocks of 1024 sorted points into two centroids, another cloud than on one
    cfg = offline_threads(Config())
    gicp = SmallGicpRegistration("gicp", cfg)
    base = gicp.align(gicp.preprocess(src), gicp.preprocess(tgt), T).T_target_source
    rc, pp = cfg.registration, cfg.preprocess
    clouds = [prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, min_range=pp.min_range,
                                   max_range=pp.max_range, threads=rc.polish_threads) for c in (src, tgt)]
    res = polish(clouds[0], clouds[1], T @ _offset(), rc)
    assert res.applied
    rot, trans = _err(res.T_target_source, base)
    assert rot < 1e-3 and trans < 1e-3, (rot, trans)


def test_convergence_tolerances_trade_iterations_for_at_most_their_size(pair):
    """registration.polish_rot_eps_deg / polish_trans_eps reach small_gicp: a looser tolerance stops in no more
    iterations, within about its own size of the tight fixed point; both land on the ground truth."""
    src, tgt, T = pair
    T0 = T @ _offset()
    tight = polish(src.polish_cloud, tgt.polish_cloud, T0, _cfg(**{"registration.polish_trans_eps": 1e-4,
                                                                   "registration.polish_rot_eps_deg": 0.01}))
    loose = polish(src.polish_cloud, tgt.polish_cloud, T0, _cfg(**{"registration.polish_trans_eps": 0.02,
                                                                   "registration.polish_rot_eps_deg": 0.5}))
    assert tight.applied and loose.applied
    assert 1 <= loose.iterations < tight.iterations
    rot, trans = _err(loose.T_target_source, tight.T_target_source)
    assert trans <= 0.02 and rot <= 0.5
    for res in (tight, loose):
        rot, trans = _err(res.T_target_source, T)
        assert rot < 0.2 and trans < 0.05


def test_a_voxel_cap_puts_a_dense_scan_on_a_coarser_grid_and_gicp_still_lands(street_pair):
    """registration.polish_max_voxels: a scan with more 0.5 m voxels than the cap gets a coarser grid with at most
    that many (and not far fewer); GICP on two capped clouds still recovers the known transform."""
    src, tgt, T = street_pair(7, 40000, [4.0, 0.3, -0.2], [1.2, 0.3, 0.03], road=True)
    clouds = [np.concatenate(c) for c in (src, tgt)]
    full = prepare_polish_cloud(clouds[0], 0.5, 20)
    cap = full.n_points // 2
    capped = [prepare_polish_cloud(c, 0.5, 20, max_voxels=cap) for c in clouds]
    assert all(0.6 * cap <= c.n_points <= cap for c in capped), ([c.n_points for c in capped], cap)
    assert prepare_polish_cloud(clouds[0], 0.5, 20, max_voxels=full.n_points + 1).n_points == full.n_points
    res = polish(capped[0], capped[1], T @ _offset(), _cfg())
    rot, trans = _err(res.T_target_source, T)
    assert res.applied and trans < 0.05 and rot < 0.15, (rot, trans)


@pytest.mark.parametrize("defer", [True, False])
def test_a_pickled_cloud_is_its_voxel_grid_with_the_rest_deferred(street_pair, defer):
    """What the node's registration process receives (a PreprocessResult the node's input thread made): its
    PolishCloud pickles as the voxel grid; the copy builds its k-d tree and covariances when it is used, the same
    ones, and the precision stage lands on the same pose."""
    import pickle

    src, tgt, T_gt = street_pair(7, 40000, [4.0, 0.3, -0.2], [1.2, 0.3, 0.03], road=True)
    clouds = [prepare_polish_cloud(np.concatenate(p), 0.5, 20, defer=defer) for p in (src, tgt)]
    copies = [pickle.loads(pickle.dumps(PreprocessResult(np.zeros((3, 3), np.float32), None, 0, 0, 0,
                                                         polish_cloud=c))).polish_cloud for c in clouds]
    for c, k in zip(clouds, copies):
        assert k.pending == (20, "GICP", c.spec[2]) and k.tree is None and k.n_points == c.n_points
        np.testing.assert_array_equal(k.points(), c.points())
    cfg = Config().registration
    T0 = T_gt.copy()
    T0[:3, 3] += (0.3, -0.2, 0.05)
    a, b = polish(clouds[0], clouds[1], T0, cfg), polish(copies[0], copies[1], T0, cfg)
    for c, k in zip(clouds, copies):
        np.testing.assert_array_equal(np.asarray(k.cloud.covs()), np.asarray(c.cloud.covs()))
    np.testing.assert_allclose(b.T_target_source, a.T_target_source, atol=1e-9)
    assert a.applied and b.applied


def test_a_view_of_a_larger_cloud_registers_in_its_own_frame(pair):
    """PolishView: the target cloud prepared once in frame B (a map's), seen from frame A through T_b_a: GICP on the
    view answers in frame A what GICP on the base answers in frame B, to rounding; its tree answers frame-A queries;
    pickled it is a plain deferred cloud of its frame-A points."""
    import pickle

    from deepbbs_ros.core import verdict
    from deepbbs_ros.core.polish import PolishView

    src, tgt, T = pair
    cfg = _cfg(**{"registration.exact_gicp": True})
    T_b_a = _offset(trans=(120.0, -35.0, 2.0), yaw_deg=73.0)  # frame A (the view's) in frame B (the base's)
    base_pts = tgt.polish_cloud.points() @ T_b_a[:3, :3].T + T_b_a[:3, 3]  # the target in frame B
    base = prepare_polish_cloud(base_pts, 0.0, 20)
    view = PolishView.of(base, tgt.polish_cloud.points(), T_b_a)
    T0 = T @ _offset()
    on_view = polish(src.polish_cloud, view, T0, cfg)
    on_base = polish(src.polish_cloud, base, T_b_a @ T0, cfg)
    assert on_view.applied and on_base.applied
    np.testing.assert_allclose(T_b_a @ on_view.T_target_source, on_base.T_target_source, atol=1e-9)
    rot, trans = _err(on_view.T_target_source, T)
    assert rot < 0.2 and trans < 0.05, (rot, trans)
    pts = src.polish_cloud.points()
    assert verdict.fitness(pts, view.tree, on_view.T_target_source, 0.5) == verdict.fitness(
        pts, base.tree, on_base.T_target_source, 0.5)
    assert view.n_points == len(view.points()) and np.array_equal(view.points(), tgt.polish_cloud.points())
    copy = pickle.loads(pickle.dumps(view))
    assert type(copy) is PolishCloud and copy.pending is not None and np.array_equal(copy.points(), view.points())
    with pytest.raises(ValueError, match="target only"):
        polish(view, base, np.eye(4), cfg)


def test_the_check_stops_a_gicp_that_wanders_and_spares_one_that_converges(pair):
    """polish(..., check=(k, score)): a GICP not converged after k iterations whose pose then scores under ``score``
    stops there, rejected and saying why; one converging before k is untouched (the same pose, bit for bit); one
    still improving with a good score runs its whole budget."""
    src, tgt, T = pair
    cfg = _cfg(**{"registration.exact_gicp": True, "registration.polish_max_iters": 50})
    good = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg)
    checked = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg, check=(good.iterations + 1, 0.3))
    assert good.applied and np.array_equal(good.T_target_source, checked.T_target_source)
    far = T @ _offset(trans=(9.0, 6.0, 0.0), yaw_deg=40.0)  # another place: nothing fits, GICP wanders
    free = polish(src.polish_cloud, tgt.polish_cloud, far, cfg)
    stopped = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.9))
    assert free.iterations > 3
    assert not stopped.applied and stopped.iterations <= 3 and stopped.check_score < 0.9
    assert stopped.reason.startswith(f"stopped after {stopped.iterations} iterations"), stopped.reason
    lenient = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.0))  # any score passes the check
    assert lenient.iterations > 3 and lenient.check_score >= 0.0


def test_the_checks_judge_stops_a_gicp_it_calls_hopeless_and_only_that(pair):
    """polish(..., check=(k, score, judge)): at the check, a pose the judge calls hopeless (False) stops there,
    rejected and saying so; a judge that lets it go on gives the pose of the check without one, bit for bit. The
    judge sees the pose after k iterations in the target's frame."""
    src, tgt, T = pair
    cfg = _cfg(**{"registration.exact_gicp": True, "registration.polish_max_iters": 50})
    far = T @ _offset(trans=(9.0, 6.0, 0.0), yaw_deg=40.0)  # another place: GICP wanders past the check
    plain = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.0))
    seen = []
    going = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.0, lambda P: seen.append(P) or True))
    assert plain.iterations > 3 and np.array_equal(plain.T_target_source, going.T_target_source)
    assert len(seen) == 1 and seen[0].shape == (4, 4) and not np.allclose(seen[0], far)
    stopped = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.0, lambda P: False))
    assert not stopped.applied and stopped.iterations <= 3 and "judged hopeless" in stopped.reason, stopped.reason
    assert np.array_equal(stopped.T_target_source, far)
    near = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg)  # converges before the check: no judge
    judged = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg,
                    check=(near.iterations + 1, 0.3, lambda P: False))
    assert near.applied and np.array_equal(near.T_target_source, judged.T_target_source)


def test_a_coarse_lead_runs_the_first_leg_and_the_whole_cloud_finishes(pair, monkeypatch):
    """polish(..., check=(k, score, judge, lead)): the first k iterations align ``lead`` (the source on a coarser
    grid) instead of the source; a start that is then hopeless stops there, having aligned the lead only; a near
    start is finished on the whole source cloud: the true pose, as without the lead (to a few mm)."""
    import small_gicp

    src, tgt, T = pair
    cfg = _cfg(**{"registration.exact_gicp": True, "registration.polish_max_iters": 50})
    lead = prepare_polish_cloud(src.polish_cloud.points(), 0.5, 20, max_voxels=2000)
    assert 0 < lead.n_points < src.polish_cloud.n_points
    sizes = []
    align = small_gicp.align
    monkeypatch.setattr(small_gicp, "align", lambda tgt_c, src_c, *a, **k: sizes.append(src_c.size()) or
                        align(tgt_c, src_c, *a, **k))
    far = T @ _offset(trans=(9.0, 6.0, 0.0), yaw_deg=40.0)
    stopped = polish(src.polish_cloud, tgt.polish_cloud, far, cfg, check=(3, 0.0, lambda P: False, lead))
    assert not stopped.applied and stopped.iterations <= 3 and "judged hopeless" in stopped.reason
    assert sizes == [lead.n_points]
    sizes.clear()
    plain = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg, check=(3, 0.3, None))
    led = polish(src.polish_cloud, tgt.polish_cloud, T @ _offset(), cfg, check=(3, 0.3, None, lead))
    n = src.polish_cloud.n_points
    assert sizes[0] == n and sizes[1] == lead.n_points and sizes[-1] == n
    assert plain.applied and led.applied, (plain.reason, led.reason)
    rot, trans = _err(led.T_target_source, plain.T_target_source)
    assert rot < 0.05 and trans < 0.01, (rot, trans)
    rot, trans = _err(led.T_target_source, T)
    assert rot < 0.2 and trans < 0.05, (rot, trans)


def test_a_scene_sized_grid_follows_the_median_range_within_its_bounds():
    """registration.polish_voxel_angle: the scene's grid is the angle at the scan's median range, in [voxel / 4,
    voxel]; the cloud stays on polish_voxel (GICP's grid) and builds the finer one on demand (finer()), and polish()
    scales its correspondence distance by the finer grid of the pair (0: as before)."""
    from deepbbs_ros.core.polish import correspondence_distance, scene_voxel

    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(5000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    near, far = dirs * 2.0, dirs * 20.0  # a corridor's ranges and a street's
    assert scene_voxel(near, 0.5, 0.125) == pytest.approx(0.25)
    assert scene_voxel(far, 0.5, 0.125) == 0.5  # never coarser than polish_voxel
    assert scene_voxel(dirs * 0.2, 0.5, 0.125) == 0.125  # never finer than a quarter of it
    small = prepare_polish_cloud(near, 0.5, 20, voxel_angle=0.125)
    large = prepare_polish_cloud(far, 0.5, 20, voxel_angle=0.125)
    plain = prepare_polish_cloud(near, 0.5, 20)
    assert (small.voxel, large.voxel, plain.voxel) == (0.5, 0.5, 0.5)
    assert small.n_points == plain.n_points  # GICP's grid: its cost
    assert (small.fine_voxel, large.fine_voxel) == (pytest.approx(0.25), 0.0)
    assert large.finer() is None and plain.finer() is None
    fine = small.finer()
    assert fine is small.finer() and fine.voxel == pytest.approx(0.25) and fine.n_points > plain.n_points
    rc = Config().registration
    assert correspondence_distance([fine, large], rc) == pytest.approx(1.0)  # 2.0 m at 0.5 m: the same ratio
    assert correspondence_distance([large, plain], rc) == 2.0
    import pickle

    again = pickle.loads(pickle.dumps(small))
    assert again.fine_voxel == pytest.approx(0.25) and again.finer().n_points == fine.n_points


def test_gicp_finishes_on_the_scene_grid_where_its_own_grid_blends_a_corridor():
    """A simulated Mid-360 in a 2-3 m corridor (no noise, no motion in the sweep: the truth exact): GICP started at
    the truth on its 0.5 m grid settles degrees off it (the grid blends walls, floor and ceiling); finished on the
    scene's grid (registration.polish_voxel_angle 1/16: 0.125 m here) it comes back to within 0.2 deg / 5 cm."""
    from deepbbs_ros.core.polish import finish
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.rig import make_simulator

    rc = Config().replace(**{"registration.polish_voxel_angle": 0.0625, "registration.polish_threads": 1,
                             "registration.exact_gicp": True}).registration
    sim = make_simulator("corridor", 2, make_sensor("mid360", range_noise=0.0, dropout=0.0), "handheld", frames=60,
                         compensate=True, motion_distortion=False)
    frames = [(sim.scan_at(k).points, sim.pose_at(k)) for k in sim.frames_apart(1.0, 3, start=10)]
    for (src, T_w_s), (tgt, T_w_t) in zip(frames[1:], frames[:-1]):
        T = np.linalg.inv(T_w_t) @ T_w_s
        sc, tc = (prepare_polish_cloud(p, 0.5, 20, voxel_angle=0.0625, threads=1) for p in (src, tgt))
        assert 0 < sc.fine_voxel < 0.2 and 0 < tc.fine_voxel < 0.2
        coarse = polish(sc, tc, T, rc)
        fine = finish(sc, tc, coarse.T_target_source, rc)
        assert coarse.applied and fine.applied, (coarse.reason, fine.reason)
        assert _err(coarse.T_target_source, T)[0] > 1.0  # GICP's own grid: its minimum off the truth
        rot, trans = _err(fine.T_target_source, T)
        assert rot < 0.2 and trans < 0.05, (rot, trans)
        plain = prepare_polish_cloud(src, 0.5, 20, threads=1)
        assert finish(plain, tc, T, rc) is None  # no scene grid: nothing to finish on
