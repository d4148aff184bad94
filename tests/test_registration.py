"""DeepBBSRegistration end to end on structured synthetic clouds with known transforms."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from deepbbs_ros.config import Config, ModelConfig
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.pair import register_pair
from deepbbs_ros.core.procrustes import weighted_procrustes
from deepbbs_ros.core.refine import refine
from deepbbs_ros.core.registration import DeepBBSRegistration, RegistrationResult
from deepbbs_ros.errors import ModelError, RegistrationError

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)


def surfaces(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random sampling (n points, metres) of one fixed street corner: walls, a car-sized box, poles."""
    k = n // 5
    u = rng.uniform(size=(n, 3))
    walls = [
        np.c_[-15 + 30 * u[:k, 0], np.full(k, 6.0), 6 * u[:k, 1]],
        np.c_[np.full(k, -9.0), -12 + 18 * u[k : 2 * k, 0], 5 * u[k : 2 * k, 1]],
        np.c_[4 + 10 * u[2 * k : 3 * k, 0], -5 - 7 * u[2 * k : 3 * k, 0], 3 * u[2 * k : 3 * k, 1]],
    ]
    ang = 2 * np.pi * u[3 * k : 4 * k, 0]
    pole = (u[3 * k : 4 * k, 1] * 4).astype(int)
    cx, cy = np.array([2.0, 8.0, -4.0, 11.0])[pole], np.array([3.0, -2.0, -7.0, 2.0])[pole]
    poles = np.c_[cx + 0.3 * np.cos(ang), cy + 0.3 * np.sin(ang), 5 * u[3 * k : 4 * k, 2]]
    m = n - 4 * k  # box 4.5 x 1.8 x 1.5 m: points on its faces
    box = u[4 * k :] * [4.5, 1.8, 1.5]
    face = rng.integers(0, 3, m)
    box[np.arange(m), face] = np.array([4.5, 1.8, 1.5])[face] * rng.integers(0, 2, m)
    return np.concatenate([*walls, poles, box + [-2.0, -3.0, 0.0]]).astype(np.float32)


def make_pair(rng, yaw_deg=3.0, t=(0.6, -0.4, 0.05), n=600, same_sampling=False):
    """(source, target, T_target_source): the source is the target scene seen from another pose."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [yaw_deg, 0.5, -0.3], degrees=True).as_matrix()
    T[:3, 3] = t
    target = surfaces(rng, n)
    scene = target if same_sampling else surfaces(rng, n)
    source = ((scene - T[:3, 3]) @ T[:3, :3]).astype(np.float32)  # p_source = R^T (p_target - t)
    return source, target, T


def errors(T_est, T_gt):
    E = np.linalg.inv(T_gt) @ T_est
    rot = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return rot, np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3])


#: the paper's pipeline (deep passes + SoftBBS refinement, no GICP precision stage): what these tests exercise
PAPER = {"registration.refine": True, "registration.max_deep_iters": 5, "registration.polish": "none"}


def tiny_registration(**flat) -> DeepBBSRegistration:
    torch.manual_seed(0)
    cfg = Config().replace(**{"registration.device": "cpu", **PAPER, **flat})
    return DeepBBSRegistration(cfg, model=DeepBBSNet(TINY).eval())


def _icp(source, target, iters=60):
    """Point-to-point ICP (1 m gate), the yardstick for what two random samplings allow."""
    from scipy.spatial import cKDTree

    tree, T = cKDTree(target), np.eye(4)
    for _ in range(iters):
        d, i = tree.query(source @ T[:3, :3].T + T[:3, 3])
        w = torch.tensor((d < 1.0) * 1.0)
        src64, tgt64 = torch.tensor(source, dtype=torch.float64), torch.tensor(target[i], dtype=torch.float64)
        R, t = weighted_procrustes(src64, tgt64, w)
        T[:3, :3], T[:3, 3] = R.numpy(), t.numpy()
    return T


def test_refinement_alone_aligns_two_samplings_and_sparse_matches_dense(rng):
    source, target, T_gt = make_pair(rng, n=1000)
    scale = 0.025
    src, tgt = torch.from_numpy(source) * scale, torch.from_numpy(target) * scale
    out = {}
    with torch.inference_mode():
        for k in (16, 0):
            r = refine(src, tgt, torch.eye(3), torch.zeros(3), k=k, max_iters=46, rot_tol_deg=0.005, trans_tol=1e-5)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = r.R.double().numpy(), r.t.double().numpy() / scale
            out[k] = (T, r.iterations)
    start = errors(np.eye(4), T_gt)
    icp = errors(_icp(source, target), T_gt)
    for k, (T, _) in out.items():
        rot, trans = errors(T, T_gt)
        # two independent samplings: as close as point-to-point ICP gets, and far closer than the start
        assert rot < max(1.5 * icp[0], 0.3) and trans < max(1.5 * icp[1], 0.05), (k, rot, trans, icp, start)
        assert rot < 0.3 * start[0] and trans < 0.15 * start[1], (k, rot, trans, start)
    rot_sd, trans_sd = errors(out[16][0], out[0][0])  # sparse vs dense: the same answer
    assert rot_sd < 0.05 and trans_sd < 0.01, (rot_sd, trans_sd)
    assert out[16][1] < 46  # stopped early on convergence


def test_register_returns_T_target_source(rng):
    """Tiny random network + refinement: the known transform, in the CONVENTIONS.md direction."""
    source, target, T_gt = make_pair(rng, same_sampling=True)
    res = tiny_registration().register(source, target, preprocessed=True)
    assert isinstance(res, RegistrationResult)
    assert res.T_target_source.dtype == np.float64 and res.T_target_source.shape == (4, 4)
    rot, trans = errors(res.T_target_source, T_gt)
    assert rot < 0.05 and trans < 0.01, (rot, trans)
    rot_inv, trans_inv = errors(np.linalg.inv(res.T_target_source), T_gt)
    assert trans_inv > 0.5  # the opposite direction is clearly wrong
    moved = source @ res.T_target_source[:3, :3].T + res.T_target_source[:3, 3]
    np.testing.assert_allclose(moved, target, atol=0.01)  # p_target = R p_source + t
    assert res.converged and res.iterations["refine"] >= 1 and 1 <= res.iterations["deep"] <= 5
    assert res.gamma.shape == (len(source),) and res.gamma.dtype == np.float32
    assert res.inlier_ratio > 0.99
    assert set(res.timings_ms) == {"preprocess", "embed", "match", "solve", "refine", "total"}
    assert res.timings_ms["total"] >= res.timings_ms["refine"] > 0


def test_T_init_is_used(rng):
    source, target, T_gt = make_pair(rng, same_sampling=True, yaw_deg=25.0, t=(6.0, 3.0, 0.0))
    reg = tiny_registration(**{"registration.deep": False})
    res = reg.register(source, target, preprocessed=True, T_init=T_gt @ _small_offset())
    rot, trans = errors(res.T_target_source, T_gt)
    assert rot < 0.05 and trans < 0.01, (rot, trans)


def _small_offset():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 2.0, degrees=True).as_matrix()
    T[:3, 3] = [0.3, -0.2, 0.0]
    return T


@pytest.mark.parametrize(
    "flat, deep, refine_iters",
    [
        ({"registration.refine": False}, (1, 5), 0),  # DeepBBS, no refinement
        ({"registration.deep": False}, (0, 0), (1, 46)),  # refinement only
        ({"registration.deep_iterations": False, "registration.refine": False}, (1, 1), 0),
        ({"registration.fixed_temperature": 0.1, "registration.refine": False}, (1, 5), 0),
        ({"registration.use_gamma": False}, (1, 5), (1, 46)),
        ({"registration.spatial_gamma": False}, (1, 5), (1, 46)),
        ({"registration.refine_k": 0, "registration.refine_max_iters": 5}, (1, 5), (1, 5)),
    ],
)
def test_ablation_switches(rng, flat, deep, refine_iters):
    source, target, _ = make_pair(rng, n=200)
    res = tiny_registration(**flat).register(source, target, preprocessed=True)
    assert deep[0] <= res.iterations["deep"] <= deep[1]
    lo, hi = refine_iters if isinstance(refine_iters, tuple) else (refine_iters, refine_iters)
    assert lo <= res.iterations["refine"] <= hi
    assert np.isfinite(res.T_target_source).all()
    R = res.T_target_source[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    if flat.get("registration.fixed_temperature") or not flat.get("registration.deep", True):
        assert res.temperature == 0.0 or res.temperature > 0


def test_raw_scans_are_preprocessed(rng):
    """Raw scans with a ground plane in: preprocessing runs and reports its time."""
    source, target, T_gt = make_pair(rng, n=3000, same_sampling=True)
    ground = np.c_[rng.uniform(-20, 20, (4000, 2)), rng.normal(scale=0.02, size=4000) - 0.0].astype(np.float32)
    src_raw = np.concatenate([source + [0, 0, 2.0], ground])
    tgt_raw = np.concatenate([target + [0, 0, 2.0], ground])
    reg = tiny_registration(**{"preprocess.num_points": 300, "preprocess.voxel_size": 0.2})
    res = reg.register(src_raw, tgt_raw)
    assert res.source.shape == (300, 3) and res.target.shape == (300, 3)
    assert res.timings_ms["preprocess"] > 0
    assert np.isfinite(res.T_target_source).all()


def test_bad_input_raises(rng):
    reg = tiny_registration()
    good = rng.normal(size=(50, 3)).astype(np.float32)
    with pytest.raises(RegistrationError, match="source: at least 3 points"):
        reg.register(good[:2], good, preprocessed=True)
    bad = good.copy()
    bad[3, 1] = np.nan
    with pytest.raises(RegistrationError, match="target: the point cloud contains NaN"):
        reg.register(good, bad, preprocessed=True)
    with pytest.raises(RegistrationError, match=r"expected an \(N, 3\) point array"):
        reg.register(good[:, :2], good, preprocessed=True)


def test_missing_weights_raise_model_error(tmp_path):
    with pytest.raises(ModelError, match=r"model file not found: .*none\.pt \(train one with deepbbs-train\)"):
        DeepBBSRegistration(Config(), weights=tmp_path / "none.pt", device="cpu")


def test_weights_from_checkpoint_and_register_pair(tmp_path, rng):
    from deepbbs_ros.core.checkpoint import save_checkpoint

    torch.manual_seed(1)
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(TINY), Config())
    source, target, T_gt = make_pair(rng, n=300, same_sampling=True)
    cfg = Config().replace(**{"registration.weights": str(path), "registration.device": "cpu", **PAPER})
    res = register_pair(source, target, cfg, preprocessed=True)
    assert errors(res.T_target_source, T_gt)[1] < 0.02
    reg = DeepBBSRegistration(cfg)
    assert reg.config.model == TINY and reg.weights_path == path


def test_register_pair_keeps_the_loaded_model(tmp_path, rng):
    """register_pair loads a checkpoint once per (file, device, config): the second call reuses it; a new
    config or a rewritten file loads again; the cache keeps two."""
    import os

    from deepbbs_ros.core import pair as core_reg
    from deepbbs_ros.core.checkpoint import save_checkpoint

    core_reg.clear_register_pair_cache()
    torch.manual_seed(1)
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(TINY), Config())
    source, target, T_gt = make_pair(rng, n=300, same_sampling=True)
    cfg = Config().replace(**{"registration.weights": str(path), "registration.device": "cpu", **PAPER})
    built = []
    real = core_reg.DeepBBSRegistration.__init__

    def counting(self, *a, **kw):
        built.append(self)
        real(self, *a, **kw)

    core_reg.DeepBBSRegistration.__init__ = counting
    try:
        first = register_pair(source, target, cfg, preprocessed=True)
        second = register_pair(source, target, cfg, preprocessed=True)
        assert len(built) == 1
        np.testing.assert_array_equal(first.T_target_source, second.T_target_source)
        assert errors(second.T_target_source, T_gt)[1] < 0.02
        register_pair(source, target, cfg.replace(**{"registration.refine_max_iters": 40}), preprocessed=True)
        assert len(built) == 2
        st = path.stat()
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # a retrained checkpoint, same name
        register_pair(source, target, cfg, preprocessed=True)
        assert len(built) == 3 and len(core_reg._PAIR_CACHE) == 2
        register_pair(source, target, cfg, preprocessed=True, model=DeepBBSNet(TINY).eval())  # never cached
        assert len(built) == 4 and len(core_reg._PAIR_CACHE) == 2
    finally:
        core_reg.DeepBBSRegistration.__init__ = real
        core_reg.clear_register_pair_cache()
    assert not core_reg._PAIR_CACHE


def test_result_repr_is_short(rng):
    """print(result) is one readable line: the transform as translation + angle, gamma as its shape."""
    from deepbbs_ros.core.preprocess import preprocess

    source, target, _ = make_pair(rng, same_sampling=True)
    res = tiny_registration().register(source, target, preprocessed=True)
    text = repr(res)
    assert len(text) < 600 and "\n" not in text, text
    assert text.startswith("RegistrationResult(T_target_source=T(t=[") and " m, rot=" in text
    assert f"gamma=array(shape=({len(source)},), dtype=float32)" in text
    assert "inlier_ratio=" in text and "converged=" in text
    pp = repr(preprocess(source, Config().preprocess.__class__(remove_ground=False, num_points=100)))
    assert pp.startswith("PreprocessResult(points=array(shape=(100, 3), dtype=float32)") and len(pp) < 600, pp


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cpu_and_cuda_registration_agree(rng):
    source, target, T_gt = make_pair(rng, same_sampling=True)
    torch.manual_seed(0)
    model = DeepBBSNet(TINY).eval()
    cfg = Config()
    cpu = DeepBBSRegistration(cfg, model=model, device="cpu").register(source, target, preprocessed=True)
    gpu = DeepBBSRegistration(cfg, model=model, device="cuda").register(source, target, preprocessed=True)
    rot, trans = errors(gpu.T_target_source, cpu.T_target_source)
    assert rot < 0.05 and trans < 0.01
    assert errors(gpu.T_target_source, T_gt)[1] < 0.01


def test_one_voxel_grid_per_scan_sampled_the_same_every_time():
    """preprocess.share_grid: the network's points are non-ground centroids of the precision stage's grid, and
    the same on every call (the grid comes back from small_gicp in a run-dependent order); without it the
    points come from the preprocessing's own voxel grid. Toy world scan (ground plane, walls, poles)."""
    from scipy.spatial import cKDTree

    from deepbbs_ros.replay.synthetic import synthetic_drive

    scan = synthetic_drive(frames=1, seed=2)[0].points
    reg = tiny_registration(**{"registration.polish": "gicp", "preprocess.num_points": 256})
    a, b = reg.preprocess(scan), reg.preprocess(scan)
    np.testing.assert_array_equal(a.points, b.points)
    grid = a.polish_cloud.points()
    assert cKDTree(grid).query(a.points)[0].max() < 1e-4  # every sampled point is a grid centroid
    assert a.n_input == len(scan) and a.n_valid == a.polish_cloud.n_cropped
    plane = a.ground_plane
    assert plane is not None
    dist = np.abs(a.points @ plane[:3] + plane[3])
    assert dist.min() > reg.config.preprocess.ground_layer / 2  # the ground layer is not sampled
    own = DeepBBSRegistration(reg.config.replace(**{"preprocess.share_grid": False}), model=reg.model).preprocess(scan)
    assert cKDTree(grid).query(own.points)[0].max() > 1e-3  # its own 0.3 m grid on the non-ground points


def test_network_threads_are_set_for_the_network_and_restored():
    """registration.threads holds while the network runs (process-wide in torch) and the caller's setting
    comes back after register()."""
    reg = tiny_registration(**{"registration.threads": 1})
    seen = []
    features = reg.model.point_features

    def spy(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return features(*args, **kwargs)

    reg.model.point_features = spy
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        source, target, _ = make_pair(np.random.default_rng(0), n=300)
        reg.register(source, target, preprocessed=True)
        assert seen and set(seen) == {1}
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_a_repeated_target_reuses_its_network_state(tmp_path, rng):
    """Registering against the same target again (a fixed map cloud), or against the last source (consecutive
    pairs), skips the target's DGCNN and transformer state and gives the numbers of a fresh registration; a
    model handed in (training) never keeps one."""
    from deepbbs_ros.core.checkpoint import save_checkpoint

    torch.manual_seed(2)
    cfg = Config().replace(**{"registration.device": "cpu", "registration.network_process": "off", **PAPER})
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(TINY), cfg)
    source, target, _ = make_pair(rng, n=300)
    other, _, _ = make_pair(np.random.default_rng(5), n=300)
    reg = DeepBBSRegistration(cfg, weights=path)
    seen = []  # the clouds (metres) whose features were computed
    features = reg.model.point_features
    reg.model.point_features = lambda xyz, idx=None: seen.append(xyz[0].numpy() / reg.model.scale) or features(xyz, idx)

    def target_computed(tgt):
        return sum(np.allclose(x, tgt, atol=1e-4) for x in seen)

    reg.register(source, target, preprocessed=True)
    assert target_computed(target) == 1
    again = reg.register(other, target, preprocessed=True)
    assert target_computed(target) == 1  # not again
    fresh = DeepBBSRegistration(cfg, weights=path).register(other, target, preprocessed=True)
    np.testing.assert_allclose(again.T_target_source, fresh.T_target_source, atol=1e-9)
    shifted = target + np.float32(0.5)  # another target: computed anew
    reg.register(other, shifted, preprocessed=True)
    assert target_computed(shifted) == 1
    # consecutive pairs (scan-to-scan): the last source, seen from identity in the first pass, is the next
    # target; its state comes from that pass
    reg.register(other, target, preprocessed=True)
    n = target_computed(other)
    nxt = reg.register(source, other, preprocessed=True)
    assert target_computed(other) == n  # not computed again as a target
    fresh = DeepBBSRegistration(cfg, weights=path).register(source, other, preprocessed=True)
    np.testing.assert_allclose(nxt.T_target_source, fresh.T_target_source, atol=1e-9)
    np.testing.assert_allclose(nxt.gamma, fresh.gamma, atol=1e-7)
    handed = DeepBBSRegistration(cfg, model=reg.model)
    handed.register(source, target, preprocessed=True)
    assert not handed.network._target_memo
