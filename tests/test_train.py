"""deepbbs-train: pair ground truth, the loss, a few steps of a tiny model, exact resume, the CLI.

Drives here are synthetic and exact: a fixed world of points on boxes and walls, and frame k holds the
world points within 30 m of the sensor expressed in the sensor frame (``inv(T_world_lidar) @ p``),
so the ground truth of every pair is known exactly.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from deepbbs_ros.config import Config
from deepbbs_ros.train.cache import Drive, check_disjoint_seeds, load_drive, save_drive
from deepbbs_ros.train.loss import deepbbs_loss, partner_mask
from deepbbs_ros.train.pairs import (
    AugmentConfig,
    PairSampler,
    frame_pairs,
    inv_T,
    make_pair,
    make_T,
    transform,
    validation_pairs,
    yaw_matrix,
)
from deepbbs_ros.train.trainer import Trainer

TINY = {
    "model.k": 6, "model.dgcnn_widths": [8, 16], "model.emb_dims": 16, "model.n_heads": 2, "model.ff_dims": 16,
    "preprocess.num_points": 64, "train.batch_size": 2, "train.steps_per_epoch": 2, "train.epochs": 2,
    "train.val_pairs": 2, "train.checkpoint_minutes": 0.0, "registration.max_deep_iters": 2,
    "registration.refine_max_iters": 5,
}


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def tiny_config(**extra) -> Config:
    return Config().replace(**{**TINY, **extra})


def synthetic_world(seed: int = 0) -> np.ndarray:
    """(P, 3) float32 points on random box faces and two long walls along x, metres."""
    rng = np.random.default_rng(seed)
    pts = []
    for side in (-12.0, 12.0):  # walls
        x = rng.uniform(-40, 80, 6000)
        pts.append(np.stack([x, np.full_like(x, side) + rng.normal(0, 0.02, x.size), rng.uniform(0, 6, x.size)], 1))
    for _ in range(40):  # boxes / poles
        c = np.array([rng.uniform(-35, 75), rng.uniform(-10, 10), 0.0])
        size = rng.uniform([0.3, 0.3, 1.0], [4.0, 4.0, 5.0])
        p = rng.uniform(-0.5, 0.5, (150, 3)) * size
        face = rng.integers(0, 2, 150)
        p[np.arange(150), face] = np.sign(p[np.arange(150), face]) * 0.5 * size[face]
        pts.append(c + p + [0, 0, 0.5 * size[2]])
    return np.concatenate(pts).astype(np.float32)


def synthetic_drive(name: str = "urban_1", frames: int = 8, seed: int = 0, has_gt: bool = True) -> Drive:
    world = synthetic_world(seed)
    rng = np.random.default_rng(seed + 1)
    poses, clouds = [], []
    for k in range(frames):
        T = make_T(yaw_matrix(np.deg2rad(3.0 * k + rng.uniform(-1, 1))), np.array([1.2 * k, 0.3 * np.sin(k), 1.9]))
        local = transform(world, inv_T(T))
        clouds.append(local[np.linalg.norm(local[:, :2], axis=1) < 30.0])
        poses.append(T)
    offsets = np.concatenate([[0], np.cumsum([len(c) for c in clouds])]).astype(np.int64)
    return Drive(name=name, points=np.concatenate(clouds), offsets=offsets,
                 T_world_lidar=np.stack(poses) if has_gt else None, stamps_ns=np.arange(frames, dtype=np.int64),
                 meta={"scene": name.split("_")[0], "seed": seed})


# -- data ----------------------------------------------------------------------------------------
def test_cache_file_round_trip(tmp_path):
    d = synthetic_drive(frames=3)
    frames = [d.frame(i) for i in range(len(d))]
    save_drive(tmp_path / "urban_1.npz", frames, d.T_world_lidar, d.stamps_ns, d.meta)
    e = load_drive(tmp_path / "urban_1.npz")
    assert len(e) == 3 and e.has_gt and e.scene == "urban"
    for i in range(3):
        np.testing.assert_array_equal(e.frame(i), frames[i])
    np.testing.assert_array_equal(e.T_world_lidar, d.T_world_lidar)
    save_drive(tmp_path / "rec.npz", frames, None, d.stamps_ns, {"scene": "recording"})
    assert not load_drive(tmp_path / "rec.npz").has_gt
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    from deepbbs_ros.errors import DatasetError

    with pytest.raises(DatasetError, match="bad.npz is not a valid drive file"):
        load_drive(tmp_path / "bad.npz")


def test_seed_splits_are_disjoint():
    check_disjoint_seeds(range(10000, 10064), range(80000, 80008), range(90000, 90016))
    from deepbbs_ros.errors import DatasetError

    with pytest.raises(DatasetError, match="scene seed 10003 is used by two splits"):
        check_disjoint_seeds(range(10000, 10010), [10003])


def test_frame_pairs_respect_max_dist():
    d = synthetic_drive(frames=8)
    pairs = frame_pairs(d, max_dist=2.5)
    pos = d.T_world_lidar[:, :3, 3]
    assert len(pairs) > 0
    assert all(i != j and np.linalg.norm(pos[i] - pos[j]) <= 2.5 for i, j in pairs)
    assert {(0, 1), (1, 0), (0, 2)} <= {tuple(p) for p in pairs.tolist()}
    assert (0, 3) not in {tuple(p) for p in pairs.tolist()}  # 3.6 m apart


@pytest.mark.parametrize("has_gt", [True, False])
def test_pairs_have_correct_ground_truth(has_gt):
    """Moving the source by T_gt puts every point onto the (full) target frame: exact views of one world."""
    d = synthetic_drive(frames=6, has_gt=has_gt)
    aug = AugmentConfig(num_points=256, max_dist=5.0, yaw_aug_deg=45.0, trans_aug=1.0, crop_prob=1.0, noise_sigma=0.0)
    rng = np.random.default_rng(3)
    for _ in range(6):
        i, j = (0, 3) if has_gt else (2, 2)
        p = make_pair(d, i, j, rng, aug)
        assert p.source.shape == (256, 3) and p.target.shape == (256, 3) and p.source.dtype == np.float32
        full_target = d.frame(j)
        moved = transform(p.source.astype(np.float64), p.T_target_source)
        dist, _ = cKDTree(full_target).query(moved)
        # points seen from frame i but outside frame j's 30 m view have no partner: allow a few
        assert np.mean(dist < 1e-3) > 0.85, np.median(dist)
        # and the transform is not trivial: without it the clouds do not match
        dist0, _ = cKDTree(full_target).query(p.source)
        assert np.median(dist0) > 0.05
        # the two clouds are independent samplings
        assert not np.allclose(np.sort(moved, axis=0), np.sort(p.target, axis=0), atol=1e-4)


def test_sampler_is_deterministic_and_validation_pairs_fixed():
    d = synthetic_drive(frames=6)
    aug = AugmentConfig(num_points=64)
    s = PairSampler([d], aug)
    a = s.batch(np.random.default_rng(5), 3)
    b = s.batch(np.random.default_rng(5), 3)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.source, y.source)
        np.testing.assert_array_equal(x.T_target_source, y.T_target_source)
    v1 = validation_pairs([d], 64, stride=2, max_dist=5.0, yaw_deg=45.0)
    v2 = validation_pairs([d], 64, stride=2, max_dist=5.0, yaw_deg=45.0)
    assert len(v1) == 3 and all(np.array_equal(p.source, q.source) for p, q in zip(v1, v2))
    pos = d.T_world_lidar[:, :3, 3]
    i, j = (int(k) for k in v1[0].ref.split(":")[1].split("->"))
    assert np.linalg.norm(pos[j] - pos[i]) <= 5.0 and (j + 1 >= len(d) or np.linalg.norm(pos[j + 1] - pos[i]) > 5.0)


def test_sampler_distance_balance():
    """train.pair_balance=distance: every drive alike, and a drive's pair distances uniform over tenths of
    max_dist (by count, a drive's close pairs outnumber its far ones); 'pairs' weighs drives by their pairs."""
    slow, fast = synthetic_drive("urban_1", frames=8), synthetic_drive("urban_2", frames=4, seed=3)
    fast.T_world_lidar[:, :3, 3] *= 1.5  # 1.8 m a frame: 1.8 and 3.6 m pairs only (6 pairs against 44)
    slow.T_world_lidar[:, :3, 3] *= 0.5  # 0.6 m a frame: 0.6 .. 4.2 m pairs, the close ones most
    counts = {}
    for balance in ("pairs", "distance"):
        s = PairSampler([slow, fast], AugmentConfig(num_points=32, pair_balance=balance))
        rng = np.random.default_rng(1)
        refs = [s.draw(rng).ref for _ in range(300)]
        ij = [(r.split(":")[0], *(int(k) for k in r.split(":")[1].split("->"))) for r in refs]
        counts[balance] = sum(n == "urban_2" for n, _, _ in ij) / len(ij)
        d = np.array([abs(j - i) for n, i, j in ij if n == "urban_1"])
        if balance == "distance":  # distances 0.6 k m, k = 1..7: one per 0.5 m bin, so each about 1/7
            assert np.all(np.abs(np.bincount(d, minlength=8)[1:] / len(d) - 1 / 7) < 0.08), np.bincount(d)
        else:  # by count: k frames apart has 2 (8 - k) pairs, the close ones most
            assert np.mean(d == 1) > 2 * np.mean(d == 6)
    assert abs(counts["distance"] - 0.5) < 0.1 and counts["pairs"] < 0.25, counts


# -- loss ------------------------------------------------------------------------------------------
def test_loss_is_zero_at_ground_truth_and_guards_no_partner():
    from deepbbs_ros.core.model import NetOutput

    g = torch.Generator().manual_seed(0)
    src = torch.randn(2, 50, 3, generator=g) * 10
    R = torch.from_numpy(np.stack([yaw_matrix(0.3), yaw_matrix(-0.5)]).astype(np.float32))
    t = torch.tensor([[1.0, 2.0, 0.1], [-3.0, 0.5, 0.0]])
    tgt = src @ R.transpose(1, 2) + t[:, None]
    perfect = NetOutput(R, t, tgt.clone(), torch.ones(2, 50), torch.ones(2))
    terms = deepbbs_loss(perfect, src, tgt, R, t, scale=0.025, theta=0.5, corr_weight=1.0)
    assert float(terms.total) < 1e-9 and float(terms.partner_ratio) == 1.0
    # a wrong translation of 1 m costs (0.025 * 1)^2 in scaled units (documented units)
    off = NetOutput(R, t + torch.tensor([1.0, 0, 0]), tgt.clone(), torch.ones(2, 50), torch.ones(2))
    terms = deepbbs_loss(off, src, tgt, R, t, scale=0.025, theta=0.5, corr_weight=1.0)
    assert float(terms.trans) == pytest.approx(0.025**2, rel=1e-4)
    # no point has a partner: the correspondence term is 0, not NaN
    far = tgt + 100.0
    assert float(partner_mask(src, far, R, t, 0.5).sum()) == 0.0
    terms = deepbbs_loss(perfect, src, far, R, t, scale=0.025, theta=0.5, corr_weight=1.0)
    assert torch.isfinite(terms.total) and float(terms.corr) == 0.0


def test_bounded_pose_loss_on_pairs_of_known_error():
    """train.pose_loss=bounded on a batch whose pose errors are known: the squared loss below the success
    tolerance, 2 (sqrt 2 - 1) c at it, and beyond it each pair's pull (gradient with respect to its rotation
    error) at most 2 sqrt(c) while the squared loss's grows with the error."""
    from deepbbs_ros.core.model import NetOutput
    from deepbbs_ros.train.loss import loss_options, tolerance_pose_term

    cfg = Config().replace(**{"train.pose_loss": "bounded", "train.trans_weight": 5.0}).validate()
    opts = loss_options(cfg, epoch=0)
    c = opts["pose_bound"]
    assert c == pytest.approx(4 * (1 - np.cos(np.radians(1.0))) + 5.0 * (0.025 * 0.3) ** 2)
    assert loss_options(Config(), 0)["pose_bound"] == 0.0  # the default: today's squared loss
    assert c == tolerance_pose_term(1.0, 0.3, scale=0.025, trans_weight=5.0)

    g = torch.Generator().manual_seed(1)
    src = torch.randn(1, 40, 3, generator=g, dtype=torch.float64) * 10
    tgt = src.clone()  # ground truth: identity

    def loss(deg: float, metres: float, pose_loss: str):
        angle = torch.tensor(np.radians(deg), dtype=torch.float64, requires_grad=True)
        cs, sn, z, o = torch.cos(angle), torch.sin(angle), torch.zeros((), dtype=torch.float64), \
            torch.ones((), dtype=torch.float64)
        R = torch.stack([torch.stack([cs, -sn, z]), torch.stack([sn, cs, z]), torch.stack([z, z, o])])[None]
        t = torch.tensor([[metres, 0.0, 0.0]], dtype=torch.float64)
        out = NetOutput(R, t, tgt.clone(), torch.ones(1, 40), torch.ones(1))
        o = loss_options(cfg.replace(**{"train.pose_loss": pose_loss}), epoch=0)
        total = deepbbs_loss(out, src, tgt, torch.eye(3, dtype=torch.float64)[None], torch.zeros(1, 3,
                             dtype=torch.float64), **o).total
        (d_angle,) = torch.autograd.grad(total, angle)
        return float(total.detach()), float(d_angle)

    # at the tolerance (1 deg, 0.3 m): the squared loss is c, the bounded 2 (sqrt 2 - 1) c
    assert loss(1.0, 0.3, "squared")[0] == pytest.approx(c, rel=1e-9)
    assert loss(1.0, 0.3, "bounded")[0] == pytest.approx(2 * (np.sqrt(2) - 1) * c, rel=1e-9)
    # well inside it the two agree
    small_sq, small_b = loss(0.02, 0.006, "squared"), loss(0.02, 0.006, "bounded")
    assert small_b[0] == pytest.approx(small_sq[0], rel=1e-3) and small_b[1] == pytest.approx(small_sq[1], rel=1e-3)
    # far beyond it: the squared loss pulls 4 sin(angle) (57x at 90 deg what it pulls at 1), the bounded one at most
    # 2 sqrt(c) per unit of the error's norm sqrt(rot) ~ sqrt(2) x angle: d/d angle <= 2 sqrt(2 c)
    # and no more than sqrt(2) x the pull of a pair whose pose term is c (a rotation alone of tol_deg)
    tol_deg = float(np.degrees(np.arccos(1 - c / 4)))
    pull_tol = loss(tol_deg, 0.0, "bounded")[1]
    for deg in (10.0, 30.0, 90.0):
        assert loss(deg, 0.0, "squared")[1] == pytest.approx(4 * np.sin(np.radians(deg)), rel=1e-9)  # d 4(1-cos)
        assert 0 < loss(deg, 0.0, "bounded")[1] <= 2 * np.sqrt(2 * c)
        assert loss(deg, 0.0, "bounded")[1] <= np.sqrt(2) * pull_tol


# -- training ------------------------------------------------------------------------------------
def test_loss_falls_on_a_fixed_batch(tmp_path):
    cfg = tiny_config(**{"train.lr": 3e-3})
    d = synthetic_drive(frames=6)
    tr = Trainer(cfg, tmp_path / "run", [d], progress=False)
    aug = AugmentConfig(num_points=64, yaw_aug_deg=20.0, crop_prob=0.0, noise_sigma=0.0)
    batch = PairSampler([d], aug).batch(np.random.default_rng(0), 4)
    losses = [tr.train_step(batch)["loss"] for _ in range(25)]
    assert np.isfinite(losses).all()
    assert np.mean(losses[-3:]) < 0.7 * np.mean(losses[:3]), losses


def _params(model):
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def test_resume_is_exact(tmp_path):
    """2 steps, save, new process-like trainer resumes, 2 more steps == 4 steps straight."""
    cfg = tiny_config()
    drives = [synthetic_drive(frames=6)]
    straight = Trainer(cfg, tmp_path / "a", drives, progress=False, curves=False)
    straight.fit(max_steps=4)
    first = Trainer(cfg, tmp_path / "b", drives, progress=False, curves=False)
    first.fit(max_steps=2)
    assert (tmp_path / "b" / "state_latest.pt").exists() and (tmp_path / "b" / "model_latest.pt").exists()
    second = Trainer(cfg, tmp_path / "b", drives, progress=False, curves=False)
    assert second.resume() == 2
    second.fit(max_steps=2)
    assert second.step == straight.step == 4
    pa, pb = _params(straight.model), _params(second.model)
    for k in pa:
        torch.testing.assert_close(pa[k], pb[k], rtol=0, atol=1e-6, msg=k)
    assert straight.rng.bit_generator.state == second.rng.bit_generator.state
    assert straight.optimizer.param_groups[0]["lr"] == second.optimizer.param_groups[0]["lr"]
    # the log holds each step once
    steps = [json.loads(ln)["step"] for ln in (tmp_path / "b" / "log.jsonl").read_text().splitlines()]
    assert steps == [1, 2, 3, 4]


def test_validation_checkpoints_and_curves(tmp_path):
    from deepbbs_ros.core.checkpoint import load_checkpoint

    cfg = tiny_config(**{"train.epochs": 1})
    tr = Trainer(cfg, tmp_path / "run", [synthetic_drive(frames=6)], [synthetic_drive("highway_9", 12, seed=9)],
                 progress=False, meta={"command": "test"})
    res = tr.fit()
    val = res["best_val"]
    assert val["plain"]["n"] == 2 and val["yaw"]["n"] == 2
    assert 0.0 <= val["plain"]["success"] <= 1.0 and np.isfinite(val["val_loss"])
    run = tmp_path / "run"
    for name in ("model_best.pt", "model_latest.pt", "state_latest.pt", "curves.png", "val.csv", "val_best.json",
                 "config.yaml", "log.jsonl"):
        assert (run / name).exists(), name
    model, ckpt_cfg, meta = load_checkpoint(run / "model_best.pt")
    assert ckpt_cfg.model.emb_dims == 16 and meta["step"] == 2 and meta["validation"]["plain"]["n"] == 2
    for k, v in model.state_dict().items():
        torch.testing.assert_close(v, tr.model.state_dict()[k])
    from deepbbs_ros.train.run_log import run_report

    text = run_report(run)
    assert "2 steps" in text and "| 2 | 1 |" in text and "model_best.pt" in text


def test_resume_rejects_a_different_model(tmp_path):
    from deepbbs_ros.errors import ModelError

    drives = [synthetic_drive(frames=4)]
    Trainer(tiny_config(), tmp_path, drives, progress=False, curves=False).fit(max_steps=1)
    other = Trainer(tiny_config(**{"model.emb_dims": 32}), tmp_path, drives, progress=False, curves=False)
    with pytest.raises(ModelError, match="different model config"):
        other.resume()
    with pytest.raises(ModelError, match="no training state"):
        other.resume(tmp_path / "missing.pt")


# -- CLI -------------------------------------------------------------------------------------------
def _tiny_cli_run(tmp_path) -> tuple:
    """(a cache of two 5-frame simulated drives, ``--set`` arguments of the tiny model) for the CLI fit tests."""
    cache = tmp_path / "cache"
    for seed in (1, 2):
        d = synthetic_drive(f"suburban_{seed}", frames=5, seed=seed)
        save_drive(cache / f"{d.name}.npz", [d.frame(i) for i in range(len(d))], d.T_world_lidar, d.stamps_ns,
                   d.meta)
    return cache, [f"--set={k}={json.dumps(v)}" for k, v in TINY.items()]


def test_cli_resume_records_the_set_list_once(tmp_path):
    """A schedule resuming with its whole --set list again: fit_args.json keeps each key once, at its first place,
    with its last value (the config the list makes is unchanged: later values win)."""
    from deepbbs_ros.cli.train import main
    from deepbbs_ros.cli.train_parser import _overrides

    cache, sets = _tiny_cli_run(tmp_path)
    run = ["fit", "--cache", str(cache), "--run", str(tmp_path / "run"), "--max-steps", "1", "--no-progress",
           "--threads", "1"]
    assert main([*run, *sets]) == 0
    first = json.loads((tmp_path / "run" / "fit_args.json").read_text())["set"]
    assert first == [s.removeprefix("--set=") for s in sets]
    for _ in range(2):
        assert main([*run, "--resume", *sets, "--set=train.lr=2e-5"]) == 0
    again = json.loads((tmp_path / "run" / "fit_args.json").read_text())["set"]
    assert again == [*first, "train.lr=2e-5"]
    assert main([*run, "--resume", "--set", "train.steps_per_epoch=3"]) == 0  # a changed value: in its place
    last = json.loads((tmp_path / "run" / "fit_args.json").read_text())["set"]
    assert len(last) == len(again) and _overrides(last) == {**_overrides(again), "train.steps_per_epoch": 3}
    assert last.index("train.steps_per_epoch=3") == again.index("train.steps_per_epoch=2")

def test_cli_fit_and_errors(tmp_path, capsys):
    from deepbbs_ros.cli.train import main

    cache, sets = _tiny_cli_run(tmp_path)
    assert main(["fit", "--cache", str(cache), "--run", str(tmp_path / "run"), "--max-steps", "1", "--no-progress",
                 "--threads", "1", *sets]) == 0
    assert main(["fit", "--run", str(tmp_path / "run"), "--resume", "--max-steps", "1", "--no-progress"]) == 0
    assert "resumed" in capsys.readouterr().err
    from deepbbs_ros.cli.train_fit import _state_model_config

    assert _state_model_config(tmp_path / "run")["emb_dims"] == 16  # a resume rebuilds the run's own network
    assert main(["fit", "--run", str(tmp_path / "r2"), "--no-progress"]) == 1
    assert "give --cache" in capsys.readouterr().err
    assert main(["fit", "--cache", str(tmp_path / "nope"), "--run", str(tmp_path / "r3"), "--no-progress"]) == 1
    assert "no such folder" in capsys.readouterr().err


def test_evaluate_reports_every_method_per_scene():
    """The model-card evaluation end to end on one short held-out drive (tiny random model)."""
    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.train.evaluate import evaluate

    cfg = tiny_config(**{"preprocess.num_points": 128})
    torch.manual_seed(0)
    report = evaluate(cfg, model=DeepBBSNet(cfg.model), scenes=["suburban"], drives_per_scene=1, frames=12,
                      stride=10, yaw_deg=45.0, progress=False)
    assert report["protocol"]["seeds"] == [90000, 90000]
    for variant in ("plain", "yaw"):
        for method in ("deepbbs++", "deepbbs", "refine-only", "gicp", "gicp-gt"):
            s = report["summary"][variant][method]
            assert s["suburban"]["pairs"] == s["all"]["pairs"] >= 1
            assert np.isfinite(s["all"]["rot_mean_deg"]) and 0 <= s["all"]["success"] <= 1
    # the plain pairs are < 5 m apart and GICP from identity registers them (sanity of the ground truth)
    assert report["summary"]["plain"]["gicp"]["all"]["success"] == 1.0
    # GICP started at the ground truth stays there on a structured suburban pair (well-conditioned)
    for variant in ("plain", "yaw"):
        assert report["summary"][variant]["gicp-gt"]["all"]["trans_max_m"] < 0.15
    assert set(report["goals"]) == {"rot_mean_deg", "trans_mean_m", "success", "success_yaw"}
    from deepbbs_ros.train.evaluate import markdown_report

    md = markdown_report(report)
    assert "| deepbbs++ | suburban |" in md and "| gicp | all |" in md and "extra random yaw up to 45 deg" in md


# -- several processes (torchrun, DistributedDataParallel on gloo) ----------------------------------
def _torchrun_fit(*args: str) -> None:
    """``torchrun --standalone --nproc_per_node 2 deepbbs-train fit ...``: 2 real CPU processes on gloo."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "deepbbs_ros.cli.train", "fit", "--no-progress", "--threads", "1", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=root)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]


def _digest(state_dict) -> str:
    import hashlib

    h = hashlib.sha256()
    for v in state_dict.values():
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def test_distributed_fit_two_processes_and_exact_resume(tmp_path):
    """2 gloo processes: each draws its own pairs, both end with the same weights (not the start's), rank 0
    alone writes the run; 2 + 2 steps with a resume between == 4 steps straight, every rank's generator too."""
    from deepbbs_ros.core.checkpoint import load_checkpoint

    cache, sets = _tiny_cli_run(tmp_path)
    _torchrun_fit("--cache", str(cache), "--run-dir", str(tmp_path / "a"), "--max-steps", "4", *sets)
    _torchrun_fit("--cache", str(cache), "--run-dir", str(tmp_path / "b"), "--max-steps", "2", *sets)
    _torchrun_fit("--run-dir", str(tmp_path / "b"), "--resume", "--max-steps", "2")

    a = torch.load(tmp_path / "a" / "state_latest.pt", weights_only=False)
    assert a["world_size"] == 2 and a["step"] == 4 and [r["rank"] for r in a["ranks"]] == [0, 1]
    r0, r1 = a["ranks"]
    assert r0["weights_sha256"] == r1["weights_sha256"] == _digest(a["model"])  # gradients were averaged
    assert r0["np_rng"] != r1["np_rng"]  # each rank drew its own pairs
    model, _, meta = load_checkpoint(tmp_path / "a" / "model_latest.pt")
    assert _digest(model.state_dict()) == r0["weights_sha256"] and meta["processes"] == 2
    start = Trainer(tiny_config(), tmp_path / "start", [synthetic_drive(frames=4)], progress=False, curves=False)
    assert _digest(start.model.state_dict()) != r0["weights_sha256"]  # the same seeded start, trained away
    # rank 0 alone wrote the run folder: each step logged once
    assert [json.loads(ln)["step"] for ln in (tmp_path / "a" / "log.jsonl").read_text().splitlines()] == [1, 2, 3, 4]

    b = torch.load(tmp_path / "b" / "state_latest.pt", weights_only=False)
    assert b["step"] == 4 and b["scheduler"] == a["scheduler"]
    assert b["optimizer"]["param_groups"][0]["lr"] == a["optimizer"]["param_groups"][0]["lr"]
    for k in a["model"]:
        torch.testing.assert_close(b["model"][k], a["model"][k], rtol=0, atol=1e-6, msg=k)
    for ra, rb in zip(a["ranks"], b["ranks"]):
        assert ra["np_rng"] == rb["np_rng"] and torch.equal(ra["torch_rng"], rb["torch_rng"])
    assert [json.loads(ln)["step"] for ln in (tmp_path / "b" / "log.jsonl").read_text().splitlines()] == [1, 2, 3, 4]
