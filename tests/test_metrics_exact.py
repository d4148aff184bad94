"""Exact metrics: the same scans in every format give the same figures, and the odometry figures are evo's.

A KITTI folder whose poses.txt keeps 6 significant digits (as KITTI's own files do: the rotations are
about 1e-6 off orthonormal) is read, and the scans read from it are written as an Apollo folder, a ROS 1
bag, a rosbag2 sqlite3 and a rosbag2 mcap recording with the package's own writers. The replay on each
must give the same metrics.json figures to 1e-9; evo's APE and RPE (its Python API, on the TUM and KITTI
trajectory files the replay wrote) must equal them to 1e-9, here and on the sample recordings in bags/.
Threads are pinned to 1 so that every run registers the same way.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepbbs_ros import metrics
from deepbbs_ros.cli.replay import main
from deepbbs_ros.datasets import open_source, write_scans
from deepbbs_ros.replay.synthetic import synthetic_drive

BAGS = Path(__file__).resolve().parents[1] / "bags"
FORMATS = {"kitti": "kitti", "apollo": "apollo", "bag": "drive.bag", "db3": "db3", "mcap": "mcap"}
TOL = 1e-9
STATS = ("mean", "rmse", "median", "max")


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "exact.yaml"
    path.write_text("eval:\n  threads: 1\n  baseline_max_iters: 30\nodometry:\n  threads: 1\n"
                    "registration:\n  polish_threads: 1\n")
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """{format: path}: one short drive as a KITTI folder with 6-digit poses and as every other format."""
    root = tmp_path_factory.mktemp("formats")
    kitti = root / FORMATS["kitti"]
    write_scans(synthetic_drive(8, seed=3, keep=0.2), kitti, "kitti")
    rows = [line.split() for line in (kitti / "poses.txt").read_text().splitlines()]
    (kitti / "poses.txt").write_text("".join(" ".join(f"{float(v):.6g}" for v in r) + "\n" for r in rows))
    scans = list(open_source(kitti))
    paths = {"kitti": kitti}
    for fmt, name in FORMATS.items():
        if fmt != "kitti":
            assert write_scans(scans, root / name, fmt) == len(scans) == 8
            paths[fmt] = root / name
    return paths


def _replay(src: Path, out: Path, config: Path, *args: str) -> tuple[dict, Path]:
    rc = main([str(src), *args, "--config", str(config), "--out", str(out), "--quiet", "--no-plots", "--no-bag"])
    assert rc == 0
    run = (out / "latest").resolve()
    return json.loads((run / "metrics.json").read_text()), run


def _figures(doc: dict) -> dict[str, float]:
    """Every error figure of metrics.json's methods, flattened (runtimes and counts left out)."""
    out = {}
    for name, m in doc["methods"].items():
        for key, v in m.items():
            if key in ("runtime_ms", "fps", "input"):
                continue
            for stat, x in (v.items() if isinstance(v, dict) else [("", v)]):
                out[f"{name}.{key}.{stat}"] = x
    return out


def _assert_same(a: dict[str, float], b: dict[str, float], what: str) -> None:
    assert a.keys() == b.keys(), what
    for k in a:
        if a[k] is None or b[k] is None:
            assert a[k] is b[k], (what, k, a[k], b[k])
        else:
            assert abs(a[k] - b[k]) <= TOL, (what, k, a[k], b[k])


def _read_traj(path: Path) -> np.ndarray:
    return metrics.read_tum(path)[1] if path.suffix == ".tum" else metrics.read_kitti(path)


# ------------------------------------------------------------------------------------------ evo
def _stats(e) -> dict[str, float]:
    s = e.get_all_statistics()
    return {k: float(s[k]) for k in STATS}


def evo_figures(gt_file: Path, est_file: Path) -> dict[str, dict[str, float]]:
    """evo's APE and RPE of ``est_file`` against ``gt_file`` (TUM or KITTI by suffix), as its CLI computes
    them: ``evo_ape -a`` (translation), ``evo_ape --pose_relation angle_deg``, ``evo_rpe`` (delta 1 frame)."""
    from evo.core import metrics as em
    from evo.core import sync
    from evo.tools import file_interface

    if gt_file.suffix == ".tum":
        ref, est = sync.associate_trajectories(file_interface.read_tum_trajectory_file(str(gt_file)),
                                               file_interface.read_tum_trajectory_file(str(est_file)))
    else:
        ref = file_interface.read_kitti_poses_file(str(gt_file))
        est = file_interface.read_kitti_poses_file(str(est_file))
    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    out = {}
    for key, metric, data in (("ate_se3_m", em.APE(em.PoseRelation.translation_part), (ref, aligned)),
                              ("ape_rot_deg", em.APE(em.PoseRelation.rotation_angle_deg), (ref, est)),
                              ("rpe_trans_m", em.RPE(em.PoseRelation.translation_part, 1, em.Unit.frames), (ref, est)),
                              ("rpe_rot_deg", em.RPE(em.PoseRelation.rotation_angle_deg, 1, em.Unit.frames),
                               (ref, est))):
        metric.process_data(data)
        out[key] = _stats(metric)
    return out


def assert_equals_evo(doc: dict, run: Path) -> int:
    """metrics.json's odometry figures against evo on every trajectory file the run wrote; returns the
    figures compared."""
    n = 0
    for name, m in doc["methods"].items():
        stem = name.replace("++", "_pp").replace("-", "_")
        for suffix in (".tum", ".kitti"):
            ev = evo_figures(run / "traj" / f"ground_truth{suffix}", run / "traj" / f"{stem}{suffix}")
            assert m["ate_rmse_m"] == pytest.approx(ev["ate_se3_m"]["rmse"], abs=TOL, rel=0)
            for key, stats in ev.items():
                for stat in STATS:
                    assert m[key][stat] == pytest.approx(stats[stat], abs=TOL, rel=0), (name, suffix, key, stat)
                    n += 1
    return n


# ------------------------------------------------------------------------------------------ tests
def test_rotation_read_from_few_digits_is_projected(recordings):
    """KITTI's 6 digits leave R^T R about 1e-6 off I; the reader projects, so the angle between a pose and
    the same pose read from another format is 0 to 1e-12 deg, not the ~0.05 deg floor of arccos."""
    raw = np.array([r.split() for r in (recordings["kitti"] / "poses.txt").read_text().splitlines()], float)
    R_raw = raw.reshape(-1, 3, 4)[:, :, :3]
    off = np.abs(np.swapaxes(R_raw, 1, 2) @ R_raw - np.eye(3)).max()
    assert off > 1e-7  # the file really is rough
    kitti = [s.T_world_lidar for s in open_source(recordings["kitti"])]
    for T in kitti:
        assert np.abs(T[:3, :3].T @ T[:3, :3] - np.eye(3)).max() < 1e-13
        assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0, abs=1e-13)
        np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    for fmt in ("apollo", "bag"):
        other = [s.T_world_lidar for s in open_source(recordings[fmt])]
        rot, tr = metrics.pair_errors(np.stack(other), np.stack(kitti))
        assert rot.max() < 1e-12 and tr.max() < 1e-12, fmt
    # the pair of a scan with itself: no error (arccos: ~1e-6 deg from rounding alone)
    T = kitti[5]
    rot, tr = metrics.pair_errors(np.eye(4), np.linalg.inv(T) @ T)
    assert rot < 1e-12 and tr < 1e-14
    assert metrics.pair_errors(np.eye(4), np.eye(4)) == (0.0, 0.0)


def test_nearest_rotation_and_stable_angle():
    rng = np.random.default_rng(4)
    R = Rotation.random(16, random_state=5).as_matrix()
    noisy = R + rng.normal(scale=1e-6, size=R.shape)
    Q = metrics.nearest_rotation(noisy)
    np.testing.assert_allclose(np.swapaxes(Q, 1, 2) @ Q, np.broadcast_to(np.eye(3), Q.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(Q), 1.0, atol=1e-14)
    assert np.abs(Q - R).max() < 1e-5  # the nearest rotation is near the one that was rounded
    np.testing.assert_allclose(metrics.nearest_rotation(R), R, atol=1e-14)  # a rotation stays itself
    reflection = np.diag([1.0, 1.0, -1.0])
    assert np.linalg.det(metrics.nearest_rotation(reflection)) == pytest.approx(1.0)  # never a reflection
    assert np.isnan(metrics.nearest_rotation(np.full((3, 3), np.nan))).all()
    T = np.eye(4)
    T[:3, :3] = noisy[0]
    T[3] = (1e-9, 0, 0, 1)
    P = metrics.project_pose(T)
    np.testing.assert_array_equal(P[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(P[:3, 3], T[:3, 3])
    # the angle is exact at every size (arccos of the trace loses everything below ~1e-8 rad)
    for angle in (1e-12, 1e-9, 1e-7, 1e-3, 0.5, 3.0, math.pi - 1e-9, math.pi):
        axis = rng.normal(size=3)
        rv = axis / np.linalg.norm(axis) * angle
        R1 = Rotation.from_rotvec(rv).as_matrix()
        assert metrics.rotation_angle(R1) == pytest.approx(angle, rel=1e-9, abs=1e-15)
        assert metrics.rotation_angle(R1) == pytest.approx(Rotation.from_matrix(R1).magnitude(), rel=1e-12, abs=1e-15)
    assert metrics.rotation_error_deg(Rotation.from_rotvec([0, 0, 1e-7]).as_matrix(), np.eye(3)) == pytest.approx(
        math.degrees(1e-7), rel=1e-9)
    assert np.isnan(metrics.rotation_angle(np.full((3, 3), np.nan)))


def test_trajectory_files_read_back_exactly(tmp_path):
    rng = np.random.default_rng(2)
    poses = np.stack([np.eye(4)] * 5)
    poses[:, :3, :3] = Rotation.random(5, random_state=3).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(5, 3)) * 100
    stamps = np.array([1_700_000_000_123_456_789 + k * 100_000_000 for k in range(5)], dtype=np.int64)
    metrics.write_tum(tmp_path / "a.tum", stamps, poses)
    metrics.write_kitti(tmp_path / "a.kitti", poses)
    s, tum = metrics.read_tum(tmp_path / "a.tum")
    assert (tmp_path / "a.tum").read_text().split()[0] == "1700000000.123456789"
    np.testing.assert_allclose(tum, poses, rtol=0, atol=1e-13)
    np.testing.assert_allclose(metrics.read_kitti(tmp_path / "a.kitti"), poses, rtol=0, atol=1e-13)
    # a KITTI trajectory of 6 digits reads as rotations
    (tmp_path / "rough.kitti").write_text("".join(" ".join(f"{v:.6g}" for v in T[:3].ravel()) + "\n" for T in poses))
    rough = metrics.read_kitti(tmp_path / "rough.kitti")
    np.testing.assert_allclose(np.swapaxes(rough[:, :3, :3], 1, 2) @ rough[:, :3, :3],
                               np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-14)
    assert metrics.rpe(rough, rough)[1].max() == 0.0


@pytest.fixture(scope="module")
def odometry_runs(recordings, config, tmp_path_factory):
    """{format: (metrics.json, run folder)} of the odometry replay of every format."""
    out = tmp_path_factory.mktemp("odometry")
    return {fmt: _replay(src, out / fmt, config, "--mode", "odometry", "--method", "gicp,kiss-icp")
            for fmt, src in recordings.items()}


def test_every_format_gives_the_same_figures(odometry_runs):
    docs = {fmt: doc for fmt, (doc, _run) in odometry_runs.items()}
    for fmt, doc in docs.items():
        assert all(m["frames"] == 8 for m in doc["methods"].values()), fmt
        _assert_same(_figures(docs["kitti"]), _figures(doc), f"kitti vs {fmt}")
    assert docs["kitti"]["methods"]["gicp"]["rpe_rot_deg"]["mean"] > 1e-4  # a figure worth comparing
    assert docs["kitti"]["definitions"]["ate_rmse_m"].endswith("evo_ape tum gt est -a)")


def test_trajectory_files_give_the_same_figures(odometry_runs):
    """The TUM and KITTI files the replay wrote, read back, give metrics.json's figures."""
    doc, run = odometry_runs["kitti"]
    for stem, name in (("gicp", "gicp"), ("kiss_icp", "kiss-icp")):
        m = doc["methods"][name]
        for suffix in (".tum", ".kitti"):
            gt = _read_traj(run / "traj" / f"ground_truth{suffix}")
            est = _read_traj(run / "traj" / f"{stem}{suffix}")
            t, r = metrics.rpe(est, gt)
            assert metrics.ate_rmse(est, gt) == pytest.approx(m["ate_rmse_m"], abs=TOL, rel=0)
            assert float(np.mean(r)) == pytest.approx(m["rpe_rot_deg"]["mean"], abs=TOL, rel=0)
            assert float(np.mean(t)) == pytest.approx(m["rpe_trans_m"]["mean"], abs=TOL, rel=0)
            assert float(np.sqrt(np.mean(metrics.ape_rotation_deg(est, gt) ** 2))) == pytest.approx(
                m["ape_rot_deg"]["rmse"], abs=TOL, rel=0)


def test_metrics_equal_evo_on_a_kitti_folder_of_few_digits(odometry_runs):
    pytest.importorskip("evo", reason="evo is a test dependency (pip install evo)")
    for fmt in ("kitti", "bag"):
        doc, run = odometry_runs[fmt]
        assert assert_equals_evo(doc, run) == 2 * 2 * 4 * 4


def test_pairs_mode_same_figures_in_every_format(recordings, config, tmp_path):
    docs = {fmt: _replay(recordings[fmt], tmp_path / fmt, config, "--mode", "pairs", "--method", "gicp",
                         "--stride", "2", "--max-dist", "3")[0]
            for fmt in ("kitti", "bag", "apollo")}
    assert docs["kitti"]["methods"]["gicp"]["pairs"] >= 3
    for fmt, doc in docs.items():
        _assert_same(_figures(docs["kitti"]), _figures(doc), f"kitti vs {fmt}")


@pytest.mark.parametrize("name", ["urban_drive_hdl64", "suburban_drive_os64", "apollo_suburban_5"])
def test_sample_recordings_metrics_equal_evo(name, config, tmp_path):
    pytest.importorskip("evo", reason="evo is a test dependency (pip install evo)")
    doc, run = _replay(BAGS / name, tmp_path / "out", config, "--mode", "odometry", "--method", "gicp",
                       "--max-frames", "6")
    assert doc["methods"]["gicp"]["frames"] == (5 if name == "apollo_suburban_5" else 6)
    assert assert_equals_evo(doc, run) == 2 * 4 * 4


def test_simulated_drive_metrics_equal_evo(config, tmp_path):
    """A drive with motion-distorted sweeps, so that the estimates carry real rotation errors."""
    pytest.importorskip("evo", reason="evo is a test dependency (pip install evo)")
    write_scans(synthetic_drive(10, seed=8, keep=0.2, motion_distortion=True), tmp_path / "drive", "mcap")
    doc, run = _replay(tmp_path / "drive", tmp_path / "out", config, "--mode", "odometry", "--method",
                       "gicp,kiss-icp")
    assert doc["methods"]["gicp"]["rpe_rot_deg"]["max"] > 1e-3
    assert assert_equals_evo(doc, run) == 2 * 2 * 4 * 4
