"""deepbbs-train adapt: the split, the triplet check, and a whole adaptation of a tiny model on a tiny recording
whose poses, when it has them, change nothing but the report."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from deepbbs_ros.cli.train import main
from deepbbs_ros.config import Config
from deepbbs_ros.core.checkpoint import load_checkpoint, save_checkpoint
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.datasets import Scan, write_scans
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.train.pairs import inv_T, make_T, transform, yaw_matrix
from deepbbs_ros.train.pseudo import Labels, cycle_consistency, split_frames

TINY = {"model.k": 6, "model.dgcnn_widths": [8, 16], "model.emb_dims": 16, "model.n_heads": 2, "model.ff_dims": 16}


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def test_split_keeps_a_gap_and_refuses_too_few_scans():
    adapt, held = split_frames(20, 0.3, 3)
    assert held == list(range(14, 20)) and adapt == list(range(0, 11))
    assert min(held) - max(adapt) == 4  # three scans between them
    with pytest.raises(DatasetError, match="too few"):
        split_frames(6, 0.3, 3)


def _chain_labels(wrong: tuple[int, int] | None) -> Labels:
    """Pairs (i, i + s), s = 1, 2, of a drive 1 m and 2 degrees a frame; ``wrong`` gets a 10-degree error."""
    poses = [make_T(yaw_matrix(np.deg2rad(2.0 * k)), np.array([1.0 * k, 0.0, 0.0])) for k in range(8)]
    ij = [(i, i + s) for s in (1, 2) for i in range(8 - s)]
    T = np.stack([inv_T(poses[j]) @ poses[i] for i, j in ij])
    if wrong is not None:
        T[ij.index(wrong)] = make_T(yaw_matrix(np.deg2rad(10.0)), np.zeros(3)) @ T[ij.index(wrong)]
    i, j = (np.array(v) for v in zip(*ij, strict=True))
    valid = np.ones(len(ij), dtype=bool)
    return Labels(i, j, T, np.ones(len(ij)), valid, valid.copy())


def test_cycle_consistency_drops_the_wrong_pair_only():
    clean = _chain_labels(None)
    counts = cycle_consistency(clean)
    assert counts["triplets"] == 6 and counts["triplets_agreeing"] == 6 and clean.kept.all()
    bad = _chain_labels((2, 4))
    cycle_consistency(bad)
    dropped = {(int(a), int(b)) for a, b, kept in zip(bad.i, bad.j, bad.kept, strict=True) if not kept}
    # the wrong pair, and its triplet's short edges: each agrees once (1-2-3, 3-4-5) and disagrees once (2-3-4), a tie
    assert dropped == {(2, 4), (2, 3), (3, 4)}


def _world(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = []
    for side in (-10.0, 10.0):
        x = rng.uniform(-30, 60, 2500)
        pts.append(np.stack([x, np.full_like(x, side), rng.uniform(-1.5, 4, x.size)], 1))
    for _ in range(30):
        c = np.array([rng.uniform(-25, 55), rng.uniform(-8, 8), 0.0])
        pts.append(c + rng.uniform(-0.8, 0.8, (80, 3)) * [1, 1, 3])
    x, y = rng.uniform(-30, 60, 3000), rng.uniform(-10, 10, 3000)
    pts.append(np.stack([x, y, np.full_like(x, -1.8)], 1))  # the ground, 1.8 m under the sensor
    return np.concatenate(pts).astype(np.float32)


def _recording(tmp_path, name: str, with_poses: bool):
    world = _world()
    scans = []
    for k in range(14):
        T = make_T(yaw_matrix(np.deg2rad(1.5 * k)), np.array([0.6 * k, 0.1 * np.sin(k), 0.0]))
        local = transform(world, inv_T(T))
        local = local[np.linalg.norm(local[:, :2], axis=1) < 35.0]
        scans.append(Scan(k, 1_000_000_000 + k * 100_000_000, local, T_world_lidar=T if with_poses else None))
    out = tmp_path / name
    write_scans(scans, out, "kitti")
    return out


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    torch.manual_seed(0)
    cfg = Config().replace(**TINY)
    path = tmp_path_factory.mktemp("w") / "tiny.pt"
    save_checkpoint(path, DeepBBSNet(cfg.model), cfg)
    return path


def _adapt(rec, out, weights, *extra) -> int:
    return main(["adapt", str(rec), "--out", str(out), "--steps", "2", "--strides", "1,2", "--held-back", "0.3",
                 "--gap", "1", "--trials", "1", "--eval-stride", "2", "--no-progress", "--threads", "1",
                 "--set", f"registration.weights={weights}", "--set", "train.batch_size=2",
                 "--set", "registration.network_process=off", *extra])


def test_adapt_needs_no_poses_and_poses_change_only_the_report(tmp_path, tiny_weights, capsys):
    bare, posed = _recording(tmp_path, "bare", False), _recording(tmp_path, "posed", True)
    assert not (bare / "poses.txt").exists()
    assert _adapt(bare, tmp_path / "a", tiny_weights) == 0
    assert _adapt(posed, tmp_path / "b", tiny_weights) == 0
    a, b = tmp_path / "a", tmp_path / "b"
    la, lb = Labels.load(a / "labels.npz"), Labels.load(b / "labels.npz")
    assert la.kept.sum() >= 1
    for field in ("i", "j", "valid", "kept"):
        np.testing.assert_array_equal(getattr(la, field), getattr(lb, field))
    np.testing.assert_allclose(la.T, lb.T, atol=1e-9)  # GICP's threads sum in any order
    wa, _, meta = load_checkpoint(a / "model_adapted.pt")
    wb, _, _ = load_checkpoint(b / "model_adapted.pt")
    for (k, va), vb in zip(wa.state_dict().items(), wb.state_dict().values(), strict=True):
        assert torch.allclose(va, vb, atol=1e-6), k  # the same training with or without the poses
    assert meta["step"] == 2
    assert any(not torch.equal(va, v0) for va, v0 in zip(wa.state_dict().values(),
                                                         load_checkpoint(tiny_weights)[0].state_dict().values(),
                                                         strict=True))
    # the report: figures only where there are poses
    ra, rb = (json.loads((d / "report.json").read_text()) for d in (a, b))
    assert ra["before"] == {"pairs": 0} and "against_poses" not in ra["labels"]
    assert rb["before"]["pairs"] >= 1 and rb["after"]["pipeline"]["perturbed"]["n"] == rb["before"]["pairs"]
    assert rb["labels"]["against_poses"]["accepted"] == rb["labels"]["accepted"]
    assert "model_adapted.pt" in capsys.readouterr().out


def test_adapt_refuses_to_overwrite_or_resume_nothing(tmp_path, tiny_weights, capsys):
    rec = _recording(tmp_path, "rec", False)
    assert _adapt(rec, tmp_path / "fresh", tiny_weights, "--resume") == 1
    assert "no adaptation state" in capsys.readouterr().err
    assert _adapt(rec, tmp_path / "run", tiny_weights) == 0
    assert _adapt(rec, tmp_path / "run", tiny_weights) == 1
    assert "--resume" in capsys.readouterr().err
    assert _adapt(rec, tmp_path / "run", tiny_weights, "--resume") == 0  # done already: labels reused, no new step
    assert load_checkpoint(tmp_path / "run" / "model_adapted.pt")[2]["step"] == 2


def test_the_report_names_its_network_row_for_what_it_runs():
    """The "network" row is the network alone (config.registration.NETWORK_ALONE) with the global search kept: the
    report calls it "network + search", not the network alone of deepbbs-replay / deepbbs-train evaluate."""
    from deepbbs_ros.config.registration import NETWORK_ALONE
    from deepbbs_ros.train.adapt_report import markdown, method_config

    cfg = Config()
    rc = method_config(cfg, "network").registration
    alone = cfg.replace(**NETWORK_ALONE).registration
    assert (rc.refine, rc.polish) == (alone.refine, alone.polish)
    assert rc.global_search == cfg.registration.global_search != alone.global_search
    assert method_config(cfg, "pipeline") is cfg
    row = {"n": 2, "success": 0.5, "basin": 1.0, "accepted": 1, "accepted_wrong": 0}
    fig = {"pairs": 1, **{m: {s: row for s in ("identity", "perturbed")} for m in ("network", "pipeline")}}
    text = markdown(fig, None, {}, {})
    assert "| network + search | identity |" in text and "| pipeline | perturbed |" in text
