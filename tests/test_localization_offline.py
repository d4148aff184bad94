"""Localization offline: ``deepbbs-bag map`` (a prior map from a recording) and ``deepbbs-replay --mode
localization`` (a recording placed in it), on tiny simulated drives of the structured test world."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from deepbbs_ros.cli.bag import main as bag_main
from deepbbs_ros.cli.replay import main as replay_main
from deepbbs_ros.config import Config
from deepbbs_ros.core.mapping import build_map
from deepbbs_ros.datasets import Scan, write_scans
from deepbbs_ros.datasets.maps import read_map, write_map
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.metrics import read_tum
from deepbbs_ros.replay import report
from deepbbs_ros.replay.runner import LocalizationResults, run_localization
from deepbbs_ros.replay.synthetic import drive_poses, scan_at, structured_world

try:  # the end-to-end run needs the map tracker
    import deepbbs_ros.core.localization  # noqa: F401

    HAVE_LOCALIZATION = True
except ImportError:
    HAVE_LOCALIZATION = False

FRAMES = 24  # the shared mapping drive (conftest.py: day1, site_map): 19 m along the road at 8 m/s, 10 Hz


def test_bag_map_from_ground_truth(day1, site_map, capsys):
    """PCD + TUM + PNG written; map points are scan points moved by the ground truth (the grid keeps the first
    point of each voxel), and every scan point has a map point within a voxel's diagonal."""
    _, scans = day1
    assert site_map.with_suffix(".tum").is_file() and site_map.with_suffix(".png").is_file()
    prior = read_map(site_map)
    assert prior.trajectory is not None and len(prior.trajectory) == FRAMES
    np.testing.assert_allclose(prior.trajectory, np.stack([s.T_world_lidar for s in scans]), atol=1e-9)
    stamps, _ = read_tum(site_map.with_suffix(".tum"))
    assert stamps[0] == pytest.approx(scans[0].stamp_s)
    cfg = Config()
    world = []
    for s in scans:
        r = np.linalg.norm(s.points, axis=1)
        p = s.points[(r >= cfg.preprocess.min_range) & (r <= cfg.preprocess.max_range)].astype(np.float64)
        world.append(p @ s.T_world_lidar[:3, :3].T + s.T_world_lidar[:3, 3])
    world = np.concatenate(world)
    d_map, _ = cKDTree(world).query(prior.points)
    assert d_map.max() < 1e-4  # float32 on file
    d_scan, _ = cKDTree(prior.points).query(world)
    assert d_scan.max() <= 0.2 * np.sqrt(3) + 1e-6
    voxels = np.unique(np.floor(prior.points / 0.2).astype(np.int64), axis=0)
    assert len(voxels) == len(prior.points)  # one point per voxel


def test_bag_map_from_odometry_lands_on_the_truth(day1, tmp_path, capsys):
    rec, scans = day1
    out = tmp_path / "odo.pcd"
    assert bag_main(["map", str(rec), str(out), "--from", "odometry", "--max-frames", "6", "--quiet",
                     "--no-plot"]) == 0
    assert "odometry poses" in capsys.readouterr().out
    prior = read_map(out)
    assert len(prior.trajectory) == 6
    truth = np.stack([s.T_world_lidar for s in scans[:6]])  # anchored at the first ground-truth pose
    assert np.abs(prior.trajectory[:, :3, 3] - truth[:, :3, 3]).max() < 0.05
    assert not out.with_suffix(".png").exists()


def test_build_map_without_scans_or_truth():
    with pytest.raises(DatasetError, match="holds no scan"):
        build_map([])
    scans = [Scan(0, 0, np.ones((50, 3)) * 5)]
    with pytest.raises(DatasetError, match="no ground-truth poses"):
        build_map(scans, source="truth")
    with pytest.raises(DatasetError, match="no scan of 1 could be placed"):
        build_map([Scan(0, 0, np.ones((50, 3)) * 500, T_world_lidar=np.eye(4))], has_ground_truth=True)  # too far


@pytest.mark.parametrize("name, message", [
    ("map.txt", "written as a .pcd file"),
    ("blocker/map.pcd", "cannot create the folder"),
])
def test_bag_map_bad_output_is_one_line(day1, tmp_path, capsys, name, message):
    (tmp_path / "blocker").write_text("a file, not a folder")
    assert bag_main(["map", str(day1[0]), str(tmp_path / name), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("deepbbs-bag: error:")


def test_map_files_ply_and_large_coordinates(tmp_path):
    """A PLY map reads like a PCD one; UTM-sized coordinates are written as float64 (no centimetres lost)."""
    import trimesh

    pts = np.random.default_rng(0).uniform(-20, 20, (300, 3))
    for encoding in ("ascii", "binary"):
        path = tmp_path / f"map_{encoding}.ply"
        path.write_bytes(trimesh.PointCloud(pts).export(file_type="ply", encoding=encoding))
        np.testing.assert_allclose(read_map(path).points, pts, atol=1e-5)
    utm = pts + [587_000.123, 4_140_000.456, 10.0]
    write_map(tmp_path / "utm.pcd", utm)
    np.testing.assert_allclose(read_map(tmp_path / "utm.pcd").points, utm, atol=1e-9)
    assert read_map(tmp_path / "utm.pcd").trajectory is None


def _query_drive(tmp_path: Path) -> Path:
    """Day 2: another stretch of the same world (starts 6 m in, 0.5 m to the left, other samples and noise)."""
    speed, rate, max_range = 8.0, 10.0, 60.0
    world = structured_world(0, length=speed * FRAMES / rate + max_range + 10)
    poses = drive_poses(FRAMES)[8:20]
    poses[:, 1, 3] += 0.5
    rng = np.random.default_rng(42)
    scans = [Scan(k, 1_800_000_000_000_000_000 + k * 100_000_000, scan_at(world, T, rng, keep=0.25),
                  frame_id="velodyne64", T_world_lidar=T) for k, T in enumerate(poses)]
    out = tmp_path / "day2"
    write_scans(scans, out, "mcap")
    return out


@pytest.mark.skipif(not HAVE_LOCALIZATION, reason="needs deepbbs_ros.core.localization")
def test_replay_localization_end_to_end(site_map, tmp_path, capsys):
    day2 = _query_drive(tmp_path)
    out = tmp_path / "results"
    assert replay_main([str(day2), "--mode", "localization", "--map", str(site_map), "--out", str(out),
                        "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "placed within tolerance" in printed and "wrong poses published" in printed
    run = out / "latest"
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["mode"] == "localization" and doc["complete"] and doc["map"]["trajectory"].endswith("site.tum")
    m = doc["methods"]["deepbbs++"]
    for key in ("scans", "placed_share", "correct_share", "wrong_published", "time_to_first_pose_ms", "recoveries",
                "latency_global_ms", "latency_tracking_ms", "events", "setup_ms"):
        assert key in m
    assert m["scans"] == 12 and m["wrong_published"] == 0
    assert m["correct_share"] >= 0.9
    with open(run / "scans.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 12
    assert {"stamp_ns", "event", "valid", "score", "path", "rot_err_deg", "trans_err_m", "mode", "time_ms",
            "candidates", "reason"} <= set(rows[0])
    assert rows[0]["mode"] == "global"
    assert (run / "results_bag" / "results_bag.mcap").is_file()
    assert (run / "localization_xy.png").is_file() and (run / "config_used.yaml").is_file()
    assert len(read_tum(run / "traj" / "localization.tum")[1]) == m["placed"]


@pytest.mark.parametrize("extra, message", [
    (["--map", "missing.pcd"], "no such map file"),
    (["--map", "map.xyz"], "a .pcd or .ply point cloud"),
    ([], "needs the prior map: --map MAP"),
])
def test_replay_localization_bad_map_is_one_line(day1, tmp_path, capsys, extra, message):
    extra = [str(tmp_path / e) if e.startswith("m") else e for e in extra]
    assert replay_main([str(day1[0]), "--mode", "localization", *extra, "--out", str(tmp_path / "r"),
                        "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("deepbbs-replay: error:")


class _ScriptedTracker:
    """A stand-in for MapTracker: the ground truth with a known offset, no pose at some scans, Ctrl-C at one."""

    def __init__(self, scans, offsets: dict[int, float], missing: set[int], stop_at: int | None = None) -> None:
        self.truth = {s.stamp_ns: s.T_world_lidar for s in scans}
        self.offsets, self.missing, self.stop_at = offsets, missing, stop_at
        self.k = 0
        self.recoveries = 0

    def step(self, points, stamp_ns, times=None):
        k, self.k = self.k, self.k + 1
        if k == self.stop_at:
            raise KeyboardInterrupt
        T = self.truth[stamp_ns].copy()
        T[0, 3] += self.offsets.get(k, 0.0)
        valid = k not in self.missing
        return SimpleNamespace(T_map_scan=T, valid=valid, score=0.9 if valid else 0.2, reason="" if valid else "no",
                               mode="global" if k == 0 else "tracking", event="found" if k == 0 else "tracking",
                               candidates=1, path="gicp", timings_ms={"total": 1.0})


def test_localization_results_metrics_outputs_and_interruption(day1, tmp_path):
    """Metrics of a scripted run (one wrong pose, two without pose); Ctrl-C keeps the scans so far; CSV, TUM and
    results bag written from them."""
    _, scans = day1
    cfg = Config()
    tracker = _ScriptedTracker(scans, offsets={5: 1.0}, missing={3, 4}, stop_at=10)
    res = run_localization(scans, tracker, cfg, results=LocalizationResults(map_xyz=np.zeros((5, 3)), map_points=5,
                                                                             setup_ms=3.0))
    assert not res.complete and "Ctrl-C" in res.errors[0] and res.frames == 10
    m = report.localization_metrics(res, cfg)["deepbbs++"]
    assert (m["scans"], m["placed"], m["correct"], m["wrong_published"], m["rejected"]) == (10, 8, 7, 1, 2)
    assert m["correct_share"] == pytest.approx(0.7) and m["first_pose_scans"] == 1
    assert m["trans_err_m"]["max"] == pytest.approx(1.0)
    assert report.table_notes("localization", {"deepbbs++": m}, True) == []  # every cell measured
    blind = {**m, "correct_share": None, "wrong_published": None, "rot_err_deg": {"p95": None},
             "trans_err_m": {"p95": None}}
    assert report.table_notes("localization", {"deepbbs++": blind}, False) == [
        "-: needs ground truth (none in this recording): placed share, times and latency only"]
    report.write_localization_csv(tmp_path / "scans.csv", res)
    with open(tmp_path / "scans.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["valid"] for r in rows[2:6]] == ["1", "0", "0", "1"] and rows[3]["x"] == ""
    report.write_localization_trajectories(tmp_path, res)
    assert len(read_tum(tmp_path / "traj" / "localization.tum")[1]) == 8
    counts = report.write_results_bag(tmp_path / "bag", res)
    assert counts == {"/deepbbs_replay/map": 1, "/deepbbs_replay/localization/pose": 8,
                      "/deepbbs_replay/ground_truth/pose": 10}
    from deepbbs_ros.replay.plots import plot_localization

    assert [p.name for p in plot_localization(tmp_path, res, 1.0, 0.3)] == ["localization_xy.png",
                                                                            "errors_over_time.png"]


def test_fleet_pools_localization_figures():
    from deepbbs_ros.replay.fleet import pool_metrics

    one = {"scans": 10, "placed": 9, "correct": 9, "wrong_published": 0, "recoveries": 1,
           "time_to_first_pose_ms": 400.0, "latency_tracking_ms": {"mean": 50.0}}
    two = {"scans": 30, "placed": 20, "correct": 18, "wrong_published": 2, "recoveries": 0,
           "time_to_first_pose_ms": 800.0, "latency_tracking_ms": {"mean": 90.0}}
    m = pool_metrics("localization", [{"deepbbs++": one}, {"deepbbs++": two}])["deepbbs++"]
    assert (m["scans"], m["placed"], m["wrong_published"], m["recoveries"]) == (40, 29, 2, 1)
    assert m["correct_share"] == pytest.approx(27 / 40) and m["time_to_first_pose_ms"]["mean"] == pytest.approx(600)
    assert m["latency_tracking_ms"]["mean"] == pytest.approx(80.0)


def test_bag_map_of_a_cut_recording_keeps_what_was_read(day1, tmp_path, capsys):
    import shutil

    cut = tmp_path / "cut"
    shutil.copytree(day1[0], cut)
    mcap = next(cut.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    assert bag_main(["map", str(cut), str(tmp_path / "cut.pcd"), "--quiet", "--no-plot"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "truncated" in err[0] and "the map of the" in err[0]
    assert 0 < len(read_map(tmp_path / "cut.pcd").trajectory) < FRAMES


def test_voxel_map_grows_as_one_grid():
    """Scans added one by one (merged in batches) give the grid of all the points at once: the first point of
    each voxel."""
    from deepbbs_ros.core.mapping import VoxelMap, voxel_down_sample

    rng = np.random.default_rng(0)
    chunks = [rng.uniform(0, 10, (3000, 3)) for _ in range(12)]
    grid = VoxelMap(0.5, flush_points=4000)
    for c in chunks:
        grid.add(c)
    once = voxel_down_sample(np.concatenate(chunks), 0.5)
    a, b = grid.points, once
    np.testing.assert_array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])
