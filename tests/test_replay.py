"""deepbbs-replay end to end on tiny recordings written with deepbbs_ros.datasets.write_scans."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros import metrics
from deepbbs_ros.cli.replay import main
from deepbbs_ros.config import Config
from deepbbs_ros.datasets import Scan, write_scans
from deepbbs_ros.replay.methods import build_methods
from deepbbs_ros.replay.runner import iter_pairs, run_odometry, run_pairs
from deepbbs_ros.replay.synthetic import synthetic_drive

try:  # DeepBBS++ joins the end-to-end runs once the core's registration entry point exists
    import deepbbs_ros.core.registration  # noqa: F401

    HAVE_CORE = True
except ImportError:
    HAVE_CORE = False


@pytest.fixture(scope="module")
def scans():
    return synthetic_drive(12, seed=0, keep=0.25)


@pytest.fixture(scope="module")
def recording(tmp_path_factory, scans):
    out = tmp_path_factory.mktemp("rec") / "drive"
    assert write_scans(scans, out, "mcap") == 12
    return out


@pytest.fixture(scope="module")
def fast_config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "fast.yaml"
    path.write_text(
        "eval:\n  threads: 1\n  baseline_max_iters: 30\n"
        "preprocess:\n  num_points: 256\n"
        "registration:\n  max_deep_iters: 2\n  refine_max_iters: 5\n  threads: 1\n"
    )
    return path


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    """A tiny random DeepBBS network saved as a checkpoint (replay only needs it to run end to end)."""
    if not HAVE_CORE:
        return None
    import torch

    from deepbbs_ros.core.checkpoint import save_checkpoint
    from deepbbs_ros.core.model import DeepBBSNet

    cfg = Config()
    cfg.model.k = 8
    cfg.model.dgcnn_widths = [16, 16]
    cfg.model.emb_dims = 32
    cfg.model.n_heads = 2
    cfg.model.ff_dims = 32
    cfg.preprocess.num_points = 256
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("w") / "tiny.pt"
    save_checkpoint(path, DeepBBSNet(cfg.model), cfg, {"note": "random tiny model for tests"})
    return path


def _methods(base: str) -> str:
    return ("deepbbs++," + base) if HAVE_CORE else base


def _weights_args(tiny_weights) -> list[str]:
    return ["--weights", str(tiny_weights), "--device", "cpu"] if tiny_weights else []


def test_iter_pairs_protocol():
    """Targets are the last frame within max_dist (1 m/frame: frame i + 5 for max_dist 5.2)."""
    poses = np.tile(np.eye(4), (30, 1, 1))
    poses[:, 0, 3] = np.arange(30)
    scans = [Scan(i, i, np.zeros((1, 3)), T_world_lidar=poses[i]) for i in range(30)]
    pairs = [(s.index, t.index) for s, t in iter_pairs(scans, stride=10, max_dist=5.2)]
    assert pairs == [(0, 5), (10, 15), (20, 25)]
    pairs = [(s.index, t.index) for s, t in iter_pairs(scans, stride=10, max_dist=5.2, max_gap=3)]
    assert pairs == [(0, 3), (10, 13), (20, 23)]
    assert [(s.index, t.index) for s, t in iter_pairs(scans, stride=28, max_dist=5.2)] == [(0, 5), (28, 29)]


def test_pairs_mode_end_to_end(recording, fast_config, tiny_weights, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main([str(recording), "--mode", "pairs", "--method", _methods("icp,gicp"), "--stride", "5",
               "--max-dist", "2.0", "--config", str(fast_config), "--out", str(out), "--quiet",
               *_weights_args(tiny_weights)])
    assert rc == 0
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["mode"] == "pairs" and doc["complete"] is True and doc["source"] == str(recording)
    assert doc["version"]
    for name in (["deepbbs++"] if HAVE_CORE else []) + ["icp", "gicp"]:
        m = doc["methods"][name]
        assert m["pairs"] == 3  # sources 0, 5, 10; targets 2 frames (1.6 m) later
        for key in ("rot_err_deg", "trans_err_m"):
            assert set(m[key]) == {"mean", "rmse", "median", "p95", "max"}
        assert set(m["runtime_ms"]) == {"mean", "p50", "p95"} and m["runtime_ms"]["mean"] > 0
        assert 0.0 <= m["success_rate"] <= 1.0
    # GICP on 1.6 m of motion in this structured world: every pair within the success thresholds
    assert doc["methods"]["gicp"]["success_rate"] == 1.0
    assert doc["methods"]["gicp"]["trans_err_m"]["max"] < 0.1
    lines = (run / "pairs.csv").read_text().splitlines()
    assert lines[0].startswith("method,pair,trial") and len(lines) == 1 + 3 * len(doc["methods"])
    import csv

    rows = list(csv.DictReader(open(run / "pairs.csv")))
    assert all(r["valid"] == "" for r in rows if r["method"] == "gicp")  # a method without a verdict
    assert all(r["path"] == "" for r in rows if r["method"] == "gicp")  # nor registration paths
    if HAVE_CORE:  # DeepBBS++'s verdict on every pose: in pairs.csv, counted in metrics.json and the table
        assert {r["valid"] for r in rows if r["method"] == "deepbbs++"} <= {"0", "1"}
        assert {r["path"] for r in rows if r["method"] == "deepbbs++"} <= {"deepbbs", "search"}  # which path answered
        m = doc["methods"]["deepbbs++"]
        assert m["accepted"] + m["rejected"] == 3 and "accepted" not in doc["methods"]["gicp"]
    for png in ("errors_cdf.png", "errors_hist.png", "errors_over_pairs.png"):
        assert (run / png).stat().st_size > 1000
    assert Config.from_yaml(run / "config_used.yaml").eval.threads == 1
    topics = _bag_topics(run / "results_bag")
    assert topics["/deepbbs_replay/gicp/pose"] == 3 and topics["/deepbbs_replay/ground_truth/pose"] == 3
    assert topics["/deepbbs_replay/gicp/aligned_cloud"] == 3 and topics["/deepbbs_replay/target_cloud"] == 3
    printed = capsys.readouterr().out
    assert "unit" in printed and "ms/pair" in printed and "results:" in printed
    assert ("poses accepted" in printed) == HAVE_CORE


def _bag_topics(path: Path) -> dict[str, int]:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages():  # every message decodes
            reader.deserialize(raw, conn.msgtype)
    return counts


def test_pairs_perturbation_trials(recording, fast_config, tmp_path):
    out = tmp_path / "out"
    rc = main([str(recording), "--method", "gicp", "--stride", "5", "--max-dist", "2.0", "--perturb-yaw", "10",
               "--perturb-trans", "0.5", "--trials", "2", "--seed", "3", "--max-pairs", "2",
               "--config", str(fast_config), "--out", str(out), "--quiet", "--no-plots", "--no-bag"])
    assert rc == 0
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["methods"]["gicp"]["pairs"] == 2 and doc["methods"]["gicp"]["registrations"] == 4
    assert doc["protocol"]["perturb_yaw_deg"] == 10.0 and doc["protocol"]["trials"] == 2
    import csv

    rows = list(csv.DictReader(open(run / "pairs.csv")))
    yaws = [abs(float(r["init_yaw_deg"])) for r in rows]
    assert all(y <= 10.0 for y in yaws) and max(yaws) > 0.5  # seeded, non-trivial perturbations


def test_odometry_mode_end_to_end(recording, fast_config, tiny_weights, tmp_path, scans):
    out = tmp_path / "out"
    rc = main([str(recording), "--mode", "odometry", "--method", _methods("kiss-icp,gicp"), "--max-frames", "8",
               "--config", str(fast_config), "--out", str(out), "--quiet", *_weights_args(tiny_weights)])
    assert rc == 0
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["mode"] == "odometry" and doc["complete"] is True
    for name, m in doc["methods"].items():
        assert m["frames"] == 8
        for key in ("kitti_t_err_pct", "kitti_r_err_deg_per_100m", "ate_rmse_m", "rpe_trans_m", "rpe_rot_deg",
                    "runtime_ms"):
            assert key in m, (name, key)
        assert m["kitti_t_err_pct"] is None  # 6 m of path: shorter than the shortest KITTI segment
    assert doc["methods"]["gicp"]["ate_rmse_m"] < 0.05
    assert doc["methods"]["kiss-icp"]["ate_rmse_m"] < 0.05
    # trajectories: evo-readable TUM/KITTI, first pose = first ground-truth pose
    stamps, gt = metrics.read_tum(run / "traj" / "ground_truth.tum")
    np.testing.assert_allclose(gt, np.stack([s.T_world_lidar for s in scans[:8]]), atol=1e-6)
    assert stamps[1] - stamps[0] == pytest.approx(0.1, abs=1e-6)
    est = metrics.read_kitti(run / "traj" / "gicp.kitti")
    np.testing.assert_allclose(est[0], scans[0].T_world_lidar, atol=1e-6)
    assert metrics.ate_rmse(est, gt) == pytest.approx(doc["methods"]["gicp"]["ate_rmse_m"], abs=1e-5)
    assert (run / "trajectory_xy.png").exists() and (run / "errors_over_time.png").exists()
    assert _bag_topics(run / "results_bag")["/deepbbs_replay/kiss_icp/odometry"] == 8
    assert len((run / "frames.csv").read_text().splitlines()) == 9


def test_odometry_without_ground_truth(scans, fast_config, tmp_path):
    bare = [Scan(s.index, s.stamp_ns, s.points, frame_id=s.frame_id) for s in scans[:6]]
    write_scans(bare, tmp_path / "nogt", "mcap")
    out = tmp_path / "out"
    rc = main([str(tmp_path / "nogt"), "--mode", "odometry", "--method", "gicp", "--config", str(fast_config),
               "--out", str(out), "--quiet", "--no-plots"])
    assert rc == 0
    run = (out / "latest").resolve()
    m = json.loads((run / "metrics.json").read_text())["methods"]["gicp"]
    assert m["frames"] == 6 and m["ate_rmse_m"] is None and m["runtime_ms"]["mean"] > 0
    est = metrics.read_kitti(run / "traj" / "gicp.kitti")
    assert est.shape == (6, 4, 4)
    np.testing.assert_allclose(est[0], np.eye(4))  # no ground truth: the trajectory starts at identity
    assert not (run / "traj" / "ground_truth.tum").exists()
    # pairs mode cannot run without ground truth: one line, exit 1
    assert main([str(tmp_path / "nogt"), "--method", "gicp", "--out", str(out), "--quiet"]) == 1


def test_reader_fault_mid_recording_keeps_results(scans, fast_config, tmp_path, capsys):
    """An Apollo folder whose 7th PCD is corrupt: it costs only its own frame (the 6 frames before it and
    the 3 after it are evaluated and written), metrics.json says complete: false and why, and the CLI
    reports one error line with exit code 1."""
    folder = tmp_path / "apollo"
    write_scans(scans[:10], folder, "apollo")
    pcds = sorted((folder / "pcds").glob("*.pcd"), key=lambda p: int(p.stem))
    pcds[6].write_bytes(pcds[6].read_bytes()[:200])  # truncated mid-header/data
    out = tmp_path / "out"
    rc = main([str(folder), "--mode", "odometry", "--method", "gicp", "--config", str(fast_config),
               "--out", str(out), "--quiet", "--no-plots", "--no-bag"])
    assert rc == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("deepbbs-replay: error: recording fault after 6 frames")
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["complete"] is False and doc["methods"]["gicp"]["frames"] == 9
    assert len(doc["errors"]) == 1 and "7.pcd" in doc["errors"][0] and "skipped" in doc["errors"][0]
    assert metrics.read_kitti(run / "traj" / "gicp.kitti").shape == (9, 4, 4)
    indices = [int(line.split(",")[1]) for line in (run / "frames.csv").read_text().splitlines()[1:]]
    assert indices == [1, 2, 3, 4, 5, 6, 8, 9, 10]  # Apollo numbers the frames from 1; 7.pcd is the damaged one


def test_interrupt_keeps_results(scans):
    """Ctrl-C mid-recording (KeyboardInterrupt from the reader): everything computed so far is kept."""

    def interrupted(n):
        yield from scans[:n]
        raise KeyboardInterrupt

    cfg = Config()
    cfg.eval.threads = 1
    methods = build_methods(["gicp"], cfg)
    res = run_odometry(interrupted(5), methods, cfg)
    assert res.complete is False and res.frames == 5 and "Ctrl-C" in res.errors[0]
    cfg.eval.stride, cfg.eval.max_dist = 2, 1.0
    pres = run_pairs(interrupted(7), methods, cfg)
    assert pres.complete is False and pres.pairs >= 2 and len(pres.records) == pres.pairs


@pytest.mark.parametrize(
    "args, message",
    [
        (["{missing}"], "no such file or directory"),
        (["{rec}", "--method", "ndt"], "unknown method 'ndt'"),
        (["{rec}", "--method", "kiss-icp"], "kiss-icp is an odometry"),
        (["{rec}", "--topic", "/nope"], "/nope"),
        (["{rec}", "--stride", "0"], "eval.stride"),
        (["{rec}", "--weights", "{missing}", "--method", "deepbbs++"], ""),
    ],
)
def test_cli_errors_are_one_line(args, message, recording, tmp_path, capsys):
    if "deepbbs++" in args and not HAVE_CORE:
        pytest.skip("core registration not available")
    argv = [a.format(missing=str(tmp_path / "missing.bag"), rec=str(recording)) for a in args]
    rc = main(argv + ["--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1 and err[0].startswith("deepbbs-replay: error:")
    assert message in err[0]


def test_plain_folder_odometry_and_table_notes(scans, fast_config, tmp_path, capsys):
    """A folder of .bin scans: odometry mode writes trajectories and runtime; the table explains its
    '-' cells (no ground truth); pairs mode refuses with one line naming what is possible."""
    folder = tmp_path / "bins"
    folder.mkdir()
    for k, scan in enumerate(scans[:5]):
        rec = np.concatenate([scan.points, np.zeros((len(scan), 1), np.float32)], axis=1).astype("<f4")
        (folder / f"{k:06d}.bin").write_bytes(rec.tobytes())
    out = tmp_path / "out"
    rc = main([str(folder), "--mode", "odometry", "--method", "gicp", "--config", str(fast_config),
               "--out", str(out), "--quiet", "--no-plots", "--no-bag"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "-: needs ground truth" in text and "only trajectories and runtime" in text
    run = (out / "latest").resolve()
    assert metrics.read_kitti(run / "traj" / "gicp.kitti").shape == (5, 4, 4)
    assert not (run / "traj" / "ground_truth.tum").exists()
    assert main([str(folder), "--method", "gicp", "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pairs mode needs ground-truth poses" in err[0] and "no errors" in err[0]


def test_short_drive_table_note_and_plots(scans, fast_config, tmp_path, capsys):
    """A drive shorter than 100 m: the drift cells are '-' and a note says why (with the drive's length);
    the plots of few pairs and of overlapping trajectories are written (error-coloured paths)."""
    from deepbbs_ros.replay import plots as P
    from deepbbs_ros.replay.report import odometry_metrics, table_notes

    cfg = Config()
    cfg.eval.threads = 1
    res = run_odometry(scans[:6], build_methods(["gicp", "icp"], cfg), cfg)
    mm = odometry_metrics(res)
    notes = table_notes("odometry", mm)
    assert len(notes) == 1 and "needs >= 100 m of path (this drive:" in notes[0]
    written = P.plot_odometry(tmp_path, res)
    assert [p.name for p in written] == ["trajectory_xy.png", "errors_over_time.png", "rpe_cdf.png"]
    cfg.eval.stride, cfg.eval.max_dist = 2, 1.0
    pres = run_pairs(scans[:6], build_methods(["gicp"], cfg), cfg)
    for r in pres.records:  # every registration failed: no finite error to put on a log axis
        r.rot_err_deg = r.trans_err_m = float("nan")
    assert len(P.plot_pairs(tmp_path, pres, 5.0, 2.0)) == 3


def test_few_pairs_get_a_hint(scans, fast_config, tmp_path, capsys):
    """A 10-scan KITTI folder at the default stride (100) gives 1 pair: a warning says why and which
    --stride gives more, a count that the pair protocol itself confirms."""
    folder = tmp_path / "kitti10"
    write_scans(scans[:10], folder, "kitti")
    out = tmp_path / "out"
    rc = main([str(folder), "--method", "gicp", "--config", str(fast_config), "--out", str(out), "--quiet",
               "--no-plots", "--no-bag"])
    assert rc == 0
    err = capsys.readouterr().err
    assert "1 pair from 10 frames" in err and "eval.stride = 100" in err and "--stride 1 gives 9 pairs" in err
    doc = json.loads(((out / "latest").resolve() / "metrics.json").read_text())
    assert doc["methods"]["gicp"]["pairs"] == 1 and any("--stride 1 gives 9 pairs" in w for w in doc["warnings"])
    assert len(list(iter_pairs(scans[:10], 1, Config().eval.max_dist))) == 9
    # enough pairs: no hint
    rc = main([str(folder), "--method", "gicp", "--stride", "1", "--max-pairs", "2", "--config", str(fast_config),
               "--out", str(out), "--quiet", "--no-plots", "--no-bag"])
    assert rc == 0 and "pairs mode takes" not in capsys.readouterr().err


def test_pair_count_matches_the_protocol_and_hints_fit():
    """count_pairs (the hint's arithmetic) = iter_pairs on random drives with gaps in the ground truth; a
    drive whose scans are farther apart than max_dist gets a --max-dist hint."""
    from deepbbs_ros.cli.replay import count_pairs, pair_count_hint

    rng = np.random.default_rng(4)
    for _ in range(20):
        n = int(rng.integers(2, 60))
        steps = rng.uniform(0.0, 4.0, (n, 3)) * [1, 1, 0]
        pos = np.cumsum(steps, axis=0)
        positions = [None if rng.random() < 0.1 else p.tolist() for p in pos]
        scans = []
        for i, p in enumerate(positions):
            T = None
            if p is not None:
                T = np.eye(4)
                T[:3, 3] = p
            scans.append(Scan(i, i, np.zeros((1, 3)), T_world_lidar=T))
        for stride in (1, 2, 5, 100):
            for dist in (1.0, 3.0, 10.0):
                want = len(list(iter_pairs(scans, stride, dist, 300)))
                assert count_pairs(positions, stride, dist, 300) == want
    ev = Config().eval
    far = [[8.0 * k, 0.0, 0.0] for k in range(30)]  # 8 m between scans, max_dist 5: no source has a target
    hint = pair_count_hint(far, ev, 0)
    assert hint.startswith("0 pairs from 30 frames") and "--max-dist 12 (the scans are 8.0 m apart)" in hint
    assert hint.endswith("gives 10 pairs") and "--stride 3 " in hint
    assert count_pairs(far, 3, 12.0, 300) == 10
    near = [[1.0 * k, 0.0, 0.0] for k in range(1000)]
    assert pair_count_hint(near, Config().eval, 10) is None  # enough pairs
    assert pair_count_hint(near[:3], Config().eval, 1) == (
        "1 pair from 3 frames: pairs mode takes a source every eval.stride = 100 frames and as its target the "
        "last frame within eval.max_dist = 5 m; --stride 1 gives 2 pairs")


@pytest.mark.parametrize(
    ("fmt", "gt_topic", "says"),
    [
        ("kitti", None, "add poses.txt to the folder (or ../../poses/nogt.txt"),
        ("apollo", None, "add poses/gt_poses.txt to the folder: one line per scan, 'index timestamp x y z qx qy"),
        ("folder", None, "a folder of scans has none: put the scans in a KITTI folder"),
        ("mcap", "/localization/pose", "give --gt-topic, one of /localization/pose"),
        ("mcap", "", "the recording has no pose topic (PoseStamped, Odometry, TransformStamped)"),
    ],
)
def test_pairs_without_ground_truth_hint_fits_the_format(scans, tmp_path, capsys, fmt, gt_topic, says):
    """Pairs mode on a recording without ground truth: one line saying where this format keeps it (a folder's
    pose file and its format; a bag's pose topics for --gt-topic), never --gt-topic for a folder."""
    src = tmp_path / "nogt"
    if fmt == "folder":
        src.mkdir()
        for k, scan in enumerate(scans[:3]):
            rec = np.concatenate([scan.points, np.zeros((len(scan), 1), np.float32)], axis=1).astype("<f4")
            (src / f"{k:06d}.bin").write_bytes(rec.tobytes())
    elif gt_topic:
        write_scans(scans[:3], src, fmt, gt_topic=gt_topic)
    else:
        write_scans([Scan(s.index, s.stamp_ns, s.points, frame_id=s.frame_id) for s in scans[:3]], src, fmt)
    assert main([str(src), "--method", "gicp", "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pairs mode needs ground-truth poses and found none: " in err[0] and says in err[0]
    assert ("--gt-topic" in err[0]) == (fmt == "mcap")
    assert "--mode odometry" in err[0]


def test_pairs_table_counts_and_verdict_cells(recording, fast_config, tiny_weights, tmp_path, capsys):
    """--trials 3 on one pair: the table shows 1 pair and 3 registrations (pairs x trials), the verdict counts
    add up to the registrations; a method without a verdict shows n/a there with its own footnote, not the
    '-' note that says every registration failed."""
    from deepbbs_ros.replay.report import table_definitions, table_notes, table_rows

    out = tmp_path / "out"
    rc = main([str(recording), "--method", _methods("gicp"), "--max-dist", "2.0", "--trials", "3",
               "--perturb-yaw", "5", "--config", str(fast_config), "--out", str(out), "--quiet", "--no-plots",
               "--no-bag", *_weights_args(tiny_weights)])
    assert rc == 0
    printed = capsys.readouterr().out
    doc = json.loads(((out / "latest").resolve() / "metrics.json").read_text())
    mm = doc["methods"]
    assert mm["gicp"]["pairs"] == 1 and mm["gicp"]["registrations"] == 3
    names, rows = table_rows("pairs", mm)
    rows = {metric: dict(zip(names, vals)) for metric, _unit, vals in rows}
    assert rows["pairs"]["gicp"] == "1" and rows["registrations"]["gicp"] == "3"
    notes = table_notes("pairs", mm)
    assert not any("failed" in n for n in notes)
    verdict = ", poses accepted / rejected" if HAVE_CORE else ""
    assert table_definitions("pairs", mm) == [f"success rate, runtime{verdict}: per registration (pairs x trials)"]
    assert "registrations" in printed and "pairs x trials" in printed
    if HAVE_CORE:
        m = mm["deepbbs++"]
        assert m["registrations"] == 3 and m["accepted"] + m["rejected"] == 3
        assert rows["poses accepted"]["gicp"] == "n/a" and rows["poses rejected"]["gicp"] == "n/a"
        assert int(rows["poses accepted"]["deepbbs++"]) + int(rows["poses rejected"]["deepbbs++"]) == 3
        assert notes == ["n/a: the method gives no verdict on its poses (DeepBBS++ accepts or rejects each)"]
        assert "n/a: the method gives no verdict" in " ".join(printed.split())
    # one trial: no registrations row, no per-registration note
    one = {n: {**m, "registrations": m["pairs"]} for n, m in mm.items()}
    assert "registrations" not in [r[0] for r in table_rows("pairs", one)[1]] and not table_definitions("pairs", one)


def test_odometry_table_says_the_ate_alignment():
    from deepbbs_ros.replay.report import table_definitions

    with_gt = {"gicp": {"frames": 8, "ate_rmse_m": 0.01}}
    assert "ATE: after one SE(3) alignment (Umeyama, no scale)" in table_definitions("odometry", with_gt)[0]
    assert table_definitions("odometry", {"gicp": {"frames": 8, "ate_rmse_m": float("nan")}}) == []


@pytest.mark.skipif(not HAVE_CORE, reason="needs the core's registration")
def test_network_alone_is_one_method_in_replay_and_evaluate(tiny_weights, monkeypatch, registration_configs):
    """``deepbbs-replay --method deepbbs`` is ``deepbbs-train evaluate --methods deepbbs``: the deep passes from the
    one start, no refinement, no precision stage, no global search; ``deepbbs++`` keeps the configured search."""
    from deepbbs_ros.core import registration
    from deepbbs_ros.train.evaluate import evaluate

    monkeypatch.setattr(registration.DeepBBSRegistration, "warmup", lambda self, *a, **k: None)
    cfg = Config()
    got = build_methods(["deepbbs++", "deepbbs"], cfg, weights=str(tiny_weights), device="cpu")
    alone = got["deepbbs"].reg.config.registration
    assert got["deepbbs++"].reg.config.registration.global_search == cfg.registration.global_search != "off"
    try:  # no drive: only the registrations it builds are looked at
        evaluate(cfg, weights=str(tiny_weights), methods=["deepbbs"], rigs=["vlp16:wheeled:courtyard"],
                 drives_per_scene=0, progress=False)
    except IndexError:  # no pair to report on
        pass
    ev = registration_configs[-1].registration  # evaluate's, the last built
    for key in ("refine", "polish", "global_search", "deep"):
        assert getattr(alone, key) == getattr(ev, key), key
    assert (alone.refine, alone.polish, alone.global_search, alone.deep) == (False, "none", "off", True)
