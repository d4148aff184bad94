"""The first day with a map: a trajectory that does not fit its map, a map in another frame than the truth, a
replay where everything failed, --start / --end, a KITTI folder without calib.txt, the node.mode hint (tiny
simulated drives; the map server over real DDS is in test_map_server.py)."""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from deepbbs_ros.cli.bag import main as bag_main
from deepbbs_ros.cli.replay import main as replay_main
from deepbbs_ros.config import Config
from deepbbs_ros.core.map_fit import check_trajectory
from deepbbs_ros.datasets import Scan, open_source, write_scans
from deepbbs_ros.datasets.maps import read_map, write_map
from deepbbs_ros.errors import ConfigError, LocalizationError
from deepbbs_ros.metrics import read_tum
from deepbbs_ros.replay.checks import frame_offset

FRAMES = 24  # the shared mapping drive (conftest.py: day1, site_map): 19 m at 8 m/s, 10 Hz


def _rz(yaw: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = t
    return T


def _moved(site_map, tmp_path, M: np.ndarray, with_tum: bool = True):
    """The map moved by M (map points p -> R p + t) into tmp_path, its old .tum beside it (the first-day mistake)."""
    prior = read_map(site_map)
    out = tmp_path / "moved.pcd"
    write_map(out, prior.points @ M[:3, :3].T + M[:3, 3])
    if with_tum:
        shutil.copy(site_map.with_suffix(".tum"), out.with_suffix(".tum"))
    return out


# -- 1. a trajectory that does not fit its map --------------------------------------------------------------------
def test_trajectory_fit_rule(site_map):
    prior = read_map(site_map)
    pts, traj = prior.points, prior.trajectory
    assert check_trajectory(pts, traj).fits and check_trajectory(pts, traj).message == ""
    far = check_trajectory(pts + [500.0, -300.0, 0.0], traj)  # the map moved far: no map around the poses
    assert not far.fits and far.off_map == far.checked == FRAMES
    assert "does not fit the map" in far.message and "free space" in far.message and "\n" not in far.message
    up = check_trajectory(pts + [0.0, 0.0, -6.0], traj)  # the map 6 m lower: the poses float above its ground
    assert not up.fits and up.bad_height == FRAMES and up.off_map == 0
    inside = traj.copy()
    inside[:, :3, 3] = pts[np.linspace(0, len(pts) - 1, FRAMES).astype(int)]  # every pose on a map point
    buried = check_trajectory(np.repeat(pts, 4, axis=0), inside)
    assert not buried.fits and buried.occupied > 0
    with pytest.raises(LocalizationError, match="expected \\(K, 4, 4\\)"):
        check_trajectory(pts, traj[:, :3])
    longer = np.concatenate([traj, traj[-3:] + np.array([[0, 0, 0, 200.0]] * 3 + [[0, 0, 0, 0]])])  # a cropped map
    part = check_trajectory(pts, longer)
    assert part.fits and part.on_map.tolist() == [True] * FRAMES + [False] * 3


@pytest.fixture(scope="module")
def registration():
    from deepbbs_ros.core.registration import DeepBBSRegistration

    return DeepBBSRegistration(Config())


def test_moved_map_uses_its_own_places_and_says_why(site_map, registration, tmp_path):
    """The localizer and the node: the trajectory is dropped with a one-line warning, the places are the grid's;
    a place with no map near it is a LocalizationError (the node's one-line 'localization_failed'), not an
    internal RegistrationError."""
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.node.localization import NodeLocalization
    from deepbbs_ros.node.map_data import MapData

    prior = read_map(_moved(site_map, tmp_path, _rz(0.4, (500.0, -300.0, 0.0))))
    loc = MapLocalizer(prior.points, Config(), registration=registration, trajectory=prior.trajectory)
    grid = MapLocalizer(prior.points, Config(), registration=registration)
    assert "does not fit the map" in loc.trajectory_warning and grid.trajectory_warning == ""
    np.testing.assert_allclose(loc.places, grid.places)
    with pytest.raises(LocalizationError, match="points within"):
        loc._crop(-1, _rz(0.0, (5000.0, 0.0, 0.0)))  # nothing of the map there

    ok = read_map(site_map)  # a map cropped after it was made: its trajectory's poses off the map are no place
    longer = np.concatenate([ok.trajectory, ok.trajectory[-3:] + _rz(0.0, (200.0, 0.0, 0.0)) - np.eye(4)])
    cropped = MapLocalizer(ok.points, Config(), registration=registration, trajectory=longer)
    whole = MapLocalizer(ok.points, Config(), registration=registration, trajectory=ok.trajectory)
    assert cropped.trajectory_warning == "" and cropped.keyframes == whole.keyframes
    np.testing.assert_allclose(cropped.places, whole.places)

    node = NodeLocalization(Config(), registration)
    try:
        line = node.build(MapData(prior.points.astype(np.float32), "map", "moved.pcd", prior.trajectory))
        assert "a grid over its free space" in line
        assert node.map_warning.startswith("map from moved.pcd: the map's trajectory does not fit the map")
        assert "keyframes of its trajectory" in node.build(MapData(ok.points.astype(np.float32), "map", "site.pcd",
                                                                  ok.trajectory))
        assert node.map_warning == ""
    finally:
        node.stop()  # its prefetch thread


# -- 8. the map and the truth in different frames -------------------------------------------------------------------
def _records(est, gt):
    return [SimpleNamespace(valid=True, T_map_est=e, T_map_gt=g) for e, g in zip(est, gt)]


def test_frame_offset_is_found_only_when_constant(day1):
    _, scans = day1
    gt = [s.T_world_lidar for s in scans]
    C = _rz(np.radians(25.0), (40.0, -12.0, 1.5))  # T_truth_map
    est = [np.linalg.inv(C) @ T for T in gt]  # the poses in a map frame the truth does not share
    rng = np.random.default_rng(0)
    jitter = [T @ _rz(rng.normal(0, 0.002), rng.normal(0, 0.03, 3)) for T in est]
    off = frame_offset(_records(jitter, gt), 1.0, 0.3)
    assert off is not None and off["poses"] == FRAMES
    np.testing.assert_allclose(off["translation_m"], C[:3, 3], atol=0.1)
    assert off["yaw_deg"] == pytest.approx(25.0, abs=0.3) and off["corrected_trans_err_m"] < 0.1
    assert "different frames" in off["message"] and "[40.0" in off["message"].replace("[39.9", "[40.0")
    assert frame_offset(_records(gt, gt), 1.0, 0.3) is None  # right as they are
    wrong = [T @ _rz(rng.uniform(-3, 3), rng.uniform(-20, 20, 3)) for T in gt]  # wrong each its own way
    assert frame_offset(_records(wrong, gt), 1.0, 0.3) is None
    assert frame_offset(_records(est[:2], gt[:2]), 1.0, 0.3) is None  # too few to tell


def test_replay_moved_map_end_to_end(day1, site_map, tmp_path, capsys):
    """A map moved after it was made, its .tum beside it, the truth in the old frame: every scan still placed (the
    map's own places), the replay records both findings and prints them, and gives the map's offset."""
    M = _rz(np.radians(30.0), (60.0, -20.0, 0.0))  # T_moved_old
    moved = _moved(site_map, tmp_path, M)
    out = tmp_path / "r"
    assert replay_main([str(day1[0]), "--mode", "localization", "--map", str(moved), "--out", str(out),
                        "--max-frames", "4", "--stride", "3", "--quiet", "--no-plots", "--no-bag"]) == 0
    err = capsys.readouterr().err
    doc = json.loads((out / "latest" / "metrics.json").read_text())
    assert doc["complete"] and doc["methods"]["deepbbs++"]["placed"] >= 3
    assert any("does not fit the map" in w for w in doc["warnings"]) and "does not fit the map" in err
    off = doc["frame_offset"]
    C = np.linalg.inv(M)  # the moved map frame in the truth's
    np.testing.assert_allclose(off["translation_m"], C[:3, 3], atol=0.5)
    assert off["yaw_deg"] == pytest.approx(-30.0, abs=1.0)
    assert "different frames" in err


# -- 3. a replay in which everything failed ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sparse(tmp_path_factory, day1):
    """A recording in millimetres (a driver's unit mistaken): every point beyond the range crop, nothing registers."""
    _, scans = day1
    tiny = [Scan(s.index, s.stamp_ns, s.points * 1000.0, frame_id=s.frame_id, T_world_lidar=s.T_world_lidar)
            for s in scans[:6]]
    out = tmp_path_factory.mktemp("sparse") / "sparse"
    write_scans(tiny, out, "mcap")
    return out


@pytest.mark.parametrize("mode, extra, says", [
    ("pairs", ["--method", "gicp", "--stride", "2"], "not one of the"),
    ("odometry", ["--method", "gicp"], "not one of the 5 registrations of the 6 frames"),
    ("localization", [], "not one of the 6 scans was placed in the map"),
])
def test_replay_where_everything_failed_says_so(sparse, site_map, tmp_path, capsys, mode, extra, says):
    out = tmp_path / "r"
    more = ["--map", str(site_map)] if mode == "localization" else []
    rc = replay_main([str(sparse), "--mode", mode, *extra, *more, "--out", str(out), "--quiet", "--no-plots",
                      "--no-bag"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith("deepbbs-replay: error: ") and says in err[0], err
    doc = json.loads((out / "latest" / "metrics.json").read_text())
    assert doc["complete"] is False and says in doc["errors"][0]
    table = {"pairs": "pairs.csv", "odometry": "frames.csv", "localization": "scans.csv"}[mode]
    assert (out / "latest" / table).is_file()  # what there is stays written


# -- 5. --start / --end ------------------------------------------------------------------------------------------
def test_start_end_split_a_drive(day1, tmp_path, capsys):
    """Seconds since the first scan, half open: the map of [0, 1.2) s and the replay of [1.2, 2.0) s share no scan."""
    rec, scans = day1
    m = tmp_path / "first.pcd"
    assert bag_main(["map", str(rec), str(m), "--end", "1.2", "--quiet", "--no-plot"]) == 0
    stamps, _ = read_tum(m.with_suffix(".tum"))
    assert len(stamps) == 12  # scans 0..11 (0.0 .. 1.1 s)
    out = tmp_path / "r"
    assert replay_main([str(rec), "--mode", "odometry", "--method", "gicp", "--start", "1.2", "--end", "2.0",
                        "--out", str(out), "--quiet", "--no-plots", "--no-bag"]) == 0
    rows = (out / "latest" / "frames.csv").read_text().splitlines()
    header = rows[0].split(",")
    first = [dict(zip(header, r.split(","))) for r in rows[1:]]
    assert [int(r["index"]) for r in first] == list(range(12, 20))
    capsys.readouterr()
    assert replay_main([str(rec), "--mode", "odometry", "--start", "9", "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no scan from --start 9 s" in err[0] and "span 2.3 s" in err[0], err
    for argv in (["--start", "-1"], ["--start", "2", "--end", "1"]):
        assert bag_main(["map", str(rec), str(tmp_path / "x.pcd"), *argv]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and ("--start must be >= 0" in err[0] or "--end must be after" in err[0]), err


# -- 6. a KITTI folder without calib.txt ------------------------------------------------------------------------
def test_kitti_without_calib_runs_odometry(day1, tmp_path, capsys):
    _, scans = day1
    folder = tmp_path / "kitti"
    write_scans(scans[:6], folder, "kitti")
    (folder / "calib.txt").unlink()
    src = open_source(folder)
    assert not src.has_ground_truth and "calib.txt" in src.warnings[0] and len(list(src)) == 6
    out = tmp_path / "r"
    assert replay_main([str(folder), "--mode", "odometry", "--method", "gicp", "--out", str(out), "--quiet",
                        "--no-plots", "--no-bag"]) == 0
    assert "calib.txt" in capsys.readouterr().err
    assert replay_main([str(folder), "--mode", "pairs", "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pairs mode needs ground-truth poses" in err[0] and "calib.txt" in err[0], err


# -- 7. node.mode:=localization -----------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["localization", "latched"])
def test_node_mode_hint_names_target_mode(mode):
    with pytest.raises(ConfigError, match=f"node.mode:=pair with node.target_mode:={mode}"):
        Config().replace(**{"node.mode": mode})
