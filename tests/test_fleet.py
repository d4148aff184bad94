"""deepbbs-replay on a fleet of recordings: a real local Ray (2 CPUs, one for the whole module), real worker
processes (one of them killed mid-task), real Ctrl-C; every recording's figures equal a single run's, with the
default thread settings, and a run on one CPU equals a run on every core."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from deepbbs_ros.cli.replay import main, replay_recording
from deepbbs_ros.config import Config
from deepbbs_ros.datasets import Scan, write_scans
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.replay import fleet
from deepbbs_ros.replay.synthetic import synthetic_drive

ray = pytest.importorskip("ray")

TIMING = {"runtime_ms", "fps"}  # the only figures that differ between two runs of the same recording


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray for every fleet test (start-up costs seconds); nothing of it is left running after."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR",
             object_store_memory=200 * 1024**2)
    session = Path(ray._private.worker._global_node.get_session_dir_path()).name
    yield
    ours = _descendants(_processes(session))  # Ray's daemons, its workers and what they started
    assert ours
    ray.shutdown()
    deadline = time.monotonic() + 20
    while _alive(ours) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(ours), "Ray processes left behind"


def _processes(needle: str) -> list[int]:
    """PIDs whose command line contains ``needle`` (Ray names a busy worker ``ray::<task>``)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and int(d.name) != os.getpid():
            try:
                if needle.encode() in (d / "cmdline").read_bytes():
                    out.append(int(d.name))
            except OSError:
                pass
    return out


def _descendants(pids: list[int]) -> set[int]:
    parent = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                parent[int(d.name)] = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    out, todo = set(pids), list(pids)
    while todo:
        p = todo.pop()
        for child, ppid in parent.items():
            if ppid == p and child not in out:
                out.add(child)
                todo.append(child)
    return out


def _alive(pids: set[int]) -> list[int]:
    alive = []
    for p in pids:
        try:
            state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
            if state != "Z":
                alive.append(p)
        except OSError:
            pass
    return alive


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    """Three good recordings, one without ground truth, one truncated, and a config that keeps them quick."""
    d = tmp_path_factory.mktemp("fleet")
    for i in range(3):
        assert write_scans(synthetic_drive(10, seed=i, keep=0.25), d / f"drive_{i}", "mcap") == 10
    bare = [Scan(s.index, s.stamp_ns, s.points, frame_id=s.frame_id) for s in synthetic_drive(6, seed=5, keep=0.25)]
    write_scans(bare, d / "no_gt", "mcap")
    mcap = next((d / "drive_0").glob("*.mcap"))
    (d / "broken").mkdir()
    (d / "broken" / "broken.mcap").write_bytes(mcap.read_bytes()[:3000])  # truncated after its header
    # quick, and no thread setting: the defaults (eval.threads) must make the figures independent of the cores
    (d / "fast.yaml").write_text("eval:\n  baseline_max_iters: 30\npreprocess:\n  num_points: 256\n"
                                 "registration:\n  max_deep_iters: 2\n")
    return d


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory):
    """A tiny random DeepBBS network (the fleet only needs DeepBBS++ to run, deterministically)."""
    import torch

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.checkpoint import save_checkpoint
    from deepbbs_ros.core.model import DeepBBSNet

    cfg = Config().replace(**{"model.k": 8, "model.dgcnn_widths": [16, 16], "model.emb_dims": 32,
                              "model.n_heads": 2, "model.ff_dims": 32, "preprocess.num_points": 256})
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("w") / "tiny.pt"
    save_checkpoint(path, DeepBBSNet(cfg.model), cfg, {"note": "random tiny model for tests"})
    return path


def _close(a, b, path=""):
    """Every figure equal to 1e-9 (timings excepted)."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            if k not in TIMING:
                _close(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, float) or isinstance(b, float):
        assert (a is None and b is None) or math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9), (path, a, b)
    else:
        assert a == b, path


def _single(source, argv, out):
    assert main([str(source), *argv, "--out", str(out), "--quiet", "--no-bag", "--no-plots"]) == 0
    return json.loads(((out / "latest").resolve() / "metrics.json").read_text())


def _per_frame(run: Path) -> list[list[str]]:
    """A run's per-pair or per-frame table (pairs.csv / frames.csv: errors, poses) without its timing columns."""
    import csv

    path = run / ("pairs.csv" if (run / "pairs.csv").exists() else "frames.csv")
    rows = list(csv.reader(path.read_text().splitlines()))
    keep = [i for i, col in enumerate(rows[0]) if not col.endswith("_ms")]
    return [[row[i] for i in keep] for row in rows]


# -- sources and pooling (no Ray) -----------------------------------------------------------------
def test_sources_paths_globs_and_lists(tmp_path):
    for name in ("a.mcap", "b.mcap", "c.bag"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "list.txt").write_text("# nightly\n../a.mcap\n\n../c.bag  # old drive\n")
    got = fleet.expand_sources([str(tmp_path / "*.mcap"), str(tmp_path / "sub" / "list.txt"),
                                str(tmp_path / "zz.mcap")])
    assert got == [str(tmp_path / "a.mcap"), str(tmp_path / "b.mcap"), str(tmp_path / "c.bag"),
                   str(tmp_path / "zz.mcap")]  # a missing recording is its own run's error
    with pytest.raises(DatasetError, match="matches no recording"):
        fleet.expand_sources([str(tmp_path / "*.db3")])
    with pytest.raises(DatasetError, match="no such source list"):
        fleet.expand_sources([str(tmp_path / "missing.txt")])
    assert fleet.recording_names(["x/drive.mcap", "y/drive.mcap", "z/drive.mcap/", "w/a b"]) == [
        "drive.mcap", "drive.mcap_2", "drive.mcap_3", "a_b"]


def test_pooled_figures_from_per_recording_metrics():
    def pairs(n, failed, rot_mean, rot_rmse, success):
        s = {"mean": rot_mean, "rmse": rot_rmse, "median": 0.0, "p95": 0.0, "max": rot_rmse * 2}
        return {"pairs": n, "registrations": n, "failed": failed, "rot_err_deg": s, "trans_err_m": s,
                "success_rate": success, "runtime_ms": {"mean": 10.0 * n, "p50": 0.0, "p95": 0.0}}

    p = fleet.pool_metrics("pairs", [{"gicp": pairs(2, 0, 1.0, 1.0, 1.0)},
                                     {"gicp": pairs(4, 1, 4.0, 2.0, 0.5)}])["gicp"]
    assert p["pairs"] == 6 and p["failed"] == 1 and p["recordings"] == 2
    assert p["rot_err_deg"]["mean"] == pytest.approx((2 * 1 + 3 * 4) / 5)  # scored registrations 2 and 3
    assert p["rot_err_deg"]["rmse"] == pytest.approx(math.sqrt((2 * 1 + 3 * 4) / 5))
    assert p["rot_err_deg"]["max"] == 4.0 and p["success_rate"] == pytest.approx((2 * 1 + 4 * 0.5) / 6)

    def odo(frames, segs, drift, ate, rt):
        s = {"mean": 0.1}
        return {"frames": frames, "kitti_segments": segs, "kitti_t_err_pct": drift, "kitti_r_err_deg_per_100m": drift,
                "ate_rmse_m": ate, "rpe_trans_m": s, "rpe_rot_deg": s, "runtime_ms": {"mean": rt}, "failed_frames": 1}

    o = fleet.pool_metrics("odometry", [{"kiss-icp": odo(11, 3, 1.0, 0.5, 20.0)},
                                        {"kiss-icp": odo(21, 1, 5.0, 1.0, 50.0)}, {}])["kiss-icp"]
    assert o["frames"] == 32 and o["kitti_segments"] == 4 and o["failed_frames"] == 2 and o["recordings"] == 2
    assert o["kitti_t_err_pct"] == pytest.approx((3 * 1 + 5) / 4)  # the mean over every segment of the fleet
    assert o["ate_rmse_m"] == pytest.approx(math.sqrt((11 * 0.25 + 21 * 1.0) / 32))
    assert o["runtime_ms"]["mean"] == pytest.approx((10 * 20 + 20 * 50) / 30) and o["fps"] == pytest.approx(25.0)


def test_fleet_task_share_of_the_machine():
    """An offline run takes every thread setting from eval.threads (1 by default), the same in a fleet task and in a
    single run; with eval.threads 0, settings of 0 (every core) mean the task's CPUs. DeepBBS++'s network process
    needs 2 of them."""
    from deepbbs_ros.cli.replay import fleet_overrides
    from deepbbs_ros.replay.runner import offline_threads

    used = offline_threads(Config())
    assert (used.eval.threads, used.registration.polish_threads, used.odometry.threads, used.registration.threads) == (
        1, 1, 1, 1)
    assert fleet_overrides(used, 1) == {"registration.network_process": "off"}
    assert fleet_overrides(used, 2) == {}
    assert offline_threads(Config().replace(**{"eval.threads": 3})).registration.polish_threads == 3
    every = offline_threads(Config().replace(**{"eval.threads": 0}))
    assert every.to_flat() == Config().replace(**{"eval.threads": 0}).to_flat()  # each section's own
    assert fleet_overrides(every, 1) == {"eval.threads": 1, "odometry.threads": 1, "registration.polish_threads": 1,
                                         "registration.network_process": "off"}
    assert fleet_overrides(every, 2) == {"eval.threads": 2, "odometry.threads": 2, "registration.polish_threads": 2}
    assert fleet_overrides(every.replace(**{"eval.threads": 3, "registration.network_process": "off"}), 1) == {
        "odometry.threads": 1, "registration.polish_threads": 1}


# -- a real fleet ----------------------------------------------------------------------------------
def test_fleet_pairs_equal_single_runs_and_failures_are_one_line(local_ray, fleet_dir, tmp_path, capsys):
    argv = ["--mode", "pairs", "--method", "icp,gicp", "--stride", "4", "--max-dist", "2.0",
            "--config", str(fleet_dir / "fast.yaml")]
    sources = [fleet_dir / "drive_0", fleet_dir / "drive_1", fleet_dir / "no_gt", fleet_dir / "broken"]
    out = tmp_path / "fleet"
    rc = main([*map(str, sources), *argv, "--workers", "2", "--out", str(out), "--quiet"])
    assert rc == 1  # two recordings cannot be evaluated
    printed = capsys.readouterr()
    assert "pooled over the fleet" in printed.out
    assert printed.err.strip().startswith("deepbbs-replay: error: 2 of 4 recordings failed")
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["kind"] == "fleet" and doc["complete"] is False and doc["recordings_ok"] == 2
    rows = {r["name"]: r for r in doc["recordings"]}
    assert [rows[n]["status"] for n in ("drive_0", "drive_1", "no_gt", "broken")] == ["ok", "ok", "failed", "failed"]
    assert "needs ground-truth poses" in rows["no_gt"]["error"] and "\n" not in rows["no_gt"]["error"]
    assert rows["broken"]["error"] and "\n" not in rows["broken"]["error"]
    assert sum("broken" in e for e in doc["errors"]) == 1
    for name in ("drive_0", "drive_1"):
        sub = run / name
        for f in ("metrics.json", "pairs.csv", "config_used.yaml", "errors_cdf.png"):
            assert (sub / f).stat().st_size > 0, f
        assert (sub / "results_bag").is_dir()
        mine = json.loads((sub / "metrics.json").read_text())
        single = _single(fleet_dir / name, argv, tmp_path / f"single_{name}")
        _close(mine["methods"], single["methods"])
        assert _per_frame(sub) == _per_frame((tmp_path / f"single_{name}" / "latest").resolve())
        _close(rows[name]["methods"], single["methods"])
        assert mine["complete"] and mine["frames_read"] == single["frames_read"] == 10
        used = Config.from_yaml(sub / "config_used.yaml")  # the task's share of the machine, recorded
        assert used.odometry.threads == 1 and used.registration.network_process == "off"
    # the pooled figures come from the per-recording ones
    pooled = fleet.pool_metrics("pairs", [rows["drive_0"]["methods"], rows["drive_1"]["methods"]])
    _close(doc["pooled"], json.loads(json.dumps(pooled)))
    assert doc["pooled"]["gicp"]["pairs"] == rows["drive_0"]["methods"]["gicp"]["pairs"] * 2
    lines = (run / "recordings.csv").read_text().splitlines()
    assert lines[0].startswith("recording,source,status") and len(lines) == 5


def test_fleet_odometry_equal_single_runs(local_ray, fleet_dir, tiny_weights, tmp_path):
    argv = ["--mode", "odometry", "--method", "gicp,kiss-icp,deepbbs++", "--config", str(fleet_dir / "fast.yaml"),
            "--weights", str(tiny_weights)]
    out = tmp_path / "fleet"
    lst = tmp_path / "drives.txt"
    lst.write_text("".join(f"{fleet_dir / n}\n" for n in ("drive_1", "drive_2")))
    assert main([str(lst), *argv, "--workers", "2", "--out", str(out), "--quiet", "--no-bag"]) == 0
    run = (out / "latest").resolve()
    doc = json.loads((run / "metrics.json").read_text())
    assert doc["complete"] and [r["name"] for r in doc["recordings"]] == ["drive_1", "drive_2"]
    for name in ("drive_1", "drive_2"):
        single = _single(fleet_dir / name, argv, tmp_path / f"single_{name}")
        _close(json.loads((run / name / "metrics.json").read_text())["methods"], single["methods"])
        there = (tmp_path / f"single_{name}" / "latest").resolve()
        assert _per_frame(run / name) == _per_frame(there)
        for method in ("gicp", "kiss_icp", "deepbbs_pp"):
            assert (run / name / "traj" / f"{method}.tum").read_text() == (there / "traj" / f"{method}.tum").read_text()
        used = Config.from_yaml(run / name / "config_used.yaml")  # what the figures came from, recorded
        assert (used.eval.threads, used.registration.polish_threads, used.odometry.threads) == (1, 1, 1)
    assert doc["pooled"]["gicp"]["frames"] == 20 and doc["pooled"]["kiss-icp"]["recordings"] == 2
    assert doc["pooled"]["deepbbs++"]["frames"] == 20


def _args(fleet_dir, **over):
    from deepbbs_ros.cli.replay import build_parser

    args = build_parser().parse_args(["x", "--mode", "odometry", "--method", "gicp", "--config",
                                      str(fleet_dir / "fast.yaml"), "--no-plots", "--no-bag"])
    for k, v in over.items():
        setattr(args, k, v)
    return args


def test_a_killed_worker_is_retried(local_ray, fleet_dir, tmp_path):
    """SIGKILL of the worker process running a recording: Ray reruns it, the fleet completes, same figures."""
    killed: list[int] = []
    stop = threading.Event()

    def killer():
        while not stop.is_set() and not killed:
            busy = _processes("ray::replay_task")
            if busy:
                os.kill(busy[0], signal.SIGKILL)
                killed.append(busy[0])
            time.sleep(0.01)

    th = threading.Thread(target=killer, daemon=True)
    mine = f"deepbbs-fleet-{os.getpid()}-*"  # this process drives the fleet: other runs' folders are not its own
    before = set(Path(tempfile.gettempdir()).glob(mine))
    th.start()
    sources = [str(fleet_dir / "drive_0"), str(fleet_dir / "drive_2")]
    try:
        res = fleet.run_fleet(replay_recording, _args(fleet_dir), sources, tmp_path, retries=2, progress=False)
    finally:
        stop.set()
        th.join()
    assert killed, "no worker was caught mid-task"
    assert res.complete and [r.status for r in res.recordings] == ["ok", "ok"]
    for src, r in zip(sources, res.recordings):
        single = _single(src, ["--mode", "odometry", "--method", "gicp", "--config", str(fleet_dir / "fast.yaml")],
                         tmp_path / f"single_{r.name}")
        _close(r.methods, single["methods"])
        assert (tmp_path / r.name / "metrics.json").exists()
    assert not set(Path(tempfile.gettempdir()).glob(mine)) - before  # the killed worker's folder too


def test_ctrl_c_keeps_finished_recordings(local_ray, fleet_dir, tmp_path):
    """Ctrl-C (a real SIGINT) once the first recording is back: it is kept, the rest is 'not run'."""
    def interrupt(rec):
        os.kill(os.getpid(), signal.SIGINT)

    sources = [str(fleet_dir / f"drive_{i}") for i in range(3)] * 2  # more recordings than CPUs
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in deepbbs-replay (rclpy tests change it)
    try:
        res = fleet.run_fleet(replay_recording, _args(fleet_dir), sources, tmp_path, progress=False,
                              on_result=interrupt)
    finally:
        signal.signal(signal.SIGINT, before)
    assert res.complete is False and any("Ctrl-C" in e for e in res.errors)
    done = [r for r in res.recordings if r.status == "ok"]
    assert done and any(r.status == "not run" for r in res.recordings)
    for r in done:
        assert json.loads((tmp_path / r.name / "metrics.json").read_text())["complete"] is True
    doc = fleet.write_summary(tmp_path, res)
    assert doc["complete"] is False and doc["recordings_ok"] == len(done)
    assert np.isfinite(doc["pooled"]["gicp"]["ate_rmse_m"])


def test_fleet_cli_errors(fleet_dir, tmp_path, capsys):
    base = [str(fleet_dir / "drive_0"), str(fleet_dir / "drive_1"), "--out", str(tmp_path), "--quiet"]
    for extra, message in ((["--workers", "0"], "--workers must be >= 1"),
                           (["--device", "cuda"], "--gpus-per-task"),
                           (["--method", "ndt"], "unknown method"),
                           (["--ray-address", "127.0.0.1:1"], "cannot reach the Ray cluster"),
                           (["--ray-address", "head-node"], "expected HOST:PORT")):
        assert main([*base, *extra]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
    assert isinstance(_args(fleet_dir), argparse.Namespace)


# -- the figures do not depend on the machine's cores --------------------------------------------------
def _replay_on(cpus: set[int], argv: list[str], out: Path) -> Path:
    """deepbbs-replay in a process of its own that may run on ``cpus`` only (its "every core" is these)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(Path(__file__).parents[1]),
                                                                     os.environ.get("PYTHONPATH", "")) if p)}
    proc = subprocess.run([sys.executable, "-m", "deepbbs_ros.cli.replay", *argv, "--out", str(out), "--quiet",
                           "--no-bag", "--no-plots"], env=env, capture_output=True, text=True, timeout=600,
                          preexec_fn=lambda: os.sched_setaffinity(0, cpus))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return (out / "latest").resolve()


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs 2 CPUs to compare a run on one with a run on all")
@pytest.mark.parametrize("mode, methods", [("odometry", "deepbbs++,gicp,kiss-icp"),
                                           ("pairs", "deepbbs++,gicp,icp,kiss-matcher")])
def test_one_cpu_equals_every_core(fleet_dir, tiny_weights, tmp_path, mode, methods):
    """Default thread settings: a run restricted to one CPU gives the figures of a run on every core, bit for bit
    (small_gicp, KISS-ICP and KISS-Matcher would otherwise sum in an order that follows the cores)."""
    argv = [str(fleet_dir / "drive_2"), "--mode", mode, "--method", methods, "--config", str(fleet_dir / "fast.yaml"),
            "--weights", str(tiny_weights)] + (["--stride", "3", "--max-dist", "2.0"] if mode == "pairs" else [])
    cpus = os.sched_getaffinity(0)
    one = _replay_on({min(cpus)}, argv, tmp_path / "one")
    every = _replay_on(cpus, argv, tmp_path / "every")
    a, b = (json.loads((run / "metrics.json").read_text())["methods"] for run in (one, every))
    _close(a, b)
    assert _per_frame(one) == _per_frame(every)
    for name in methods.split(","):
        if mode == "pairs":
            assert a[name]["registrations"] > 0
        for key in ("ate_rmse_m",) if mode == "odometry" else ("rot_err_deg", "trans_err_m"):
            assert a[name][key] == b[name][key], (name, key)  # bit for bit, not only to 1e-9
