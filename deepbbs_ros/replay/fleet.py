"""A fleet of recordings replayed as Ray tasks: one task per recording, one results folder.

``deepbbs-replay A B C --workers 2`` (or ``--ray-address ADDR``) runs every recording through the very
function a single ``deepbbs-replay SOURCE`` run uses (handed in by the CLI as ``replay_one``), in a Ray
worker process, into a private temporary folder. The task sends back what that run wrote (metrics.json,
CSV, trajectories, plots, results bag: bytes, never point clouds) and the driver lays it out as::

    OUT/<timestamp>/
        metrics.json      the fleet summary: per-recording rows + pooled figures per method
        recordings.csv    the per-recording table
        <recording>/      exactly what ``deepbbs-replay <recording>`` writes into its own run folder

The pooled figures are computed from the per-recording metrics (see :func:`pool_metrics`), never
re-estimated. A recording that fails is a row with its one-line error; a worker process that dies is
retried by Ray (``retries``); Ctrl-C keeps every recording finished so far and marks the run incomplete.
No ROS import; Ray is imported only when a fleet runs.
"""

from __future__ import annotations

import csv
import datetime as _dt
import glob
import io
import json
import logging
import math
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deepbbs_ros import __version__
from deepbbs_ros.errors import ConfigError, DatasetError, DeepBBSError

LIST_SUFFIXES = (".txt", ".list")  # a source with this suffix is a text file naming one source per line


# --------------------------------------------------------------------------------------------------
# sources
# --------------------------------------------------------------------------------------------------
def expand_sources(items: list[str]) -> list[str]:
    """Paths as given, globs (``'drives/*.mcap'``, quoted so the shell leaves them) and list files
    (``*.txt`` / ``*.list``: one source per line, ``#`` comments, paths relative to the list's folder)
    -> the recordings in order, duplicates dropped. A glob that matches nothing or a missing list file is
    a :class:`DatasetError`; a missing recording is left for its own run to report."""
    out: list[str] = []

    def add(item: str, base: Path | None) -> None:
        path = Path(item)
        if base is not None and not path.is_absolute():
            path = Path(os.path.normpath(base / path))
        text = str(path)
        if path.suffix.lower() in LIST_SUFFIXES and not path.is_dir():
            if not path.is_file():
                raise DatasetError(f"{text}: no such source list")
            for ln in path.read_text().splitlines():
                ln = ln.split("#", 1)[0].strip()
                if ln:
                    add(ln, path.parent)
            return
        if any(c in item for c in "*?[") and not path.exists():
            hits = sorted(glob.glob(text))
            if not hits:
                raise DatasetError(f"{text}: the pattern matches no recording")
            for h in hits:
                add(h, None)
            return
        if text not in out:
            out.append(text)

    for item in items:
        add(item, None)
    if not out:
        raise DatasetError("no recording given (empty source list)")
    return out


def recording_names(sources: list[str]) -> list[str]:
    """A folder name per recording: its file or folder name (``drive_03.mcap``), made filesystem-safe,
    suffixed ``_2``, ``_3`` ... when two recordings share a name."""
    names: list[str] = []
    for src in sources:
        base = re.sub(r"[^A-Za-z0-9._+-]", "_", Path(src.rstrip("/")).name) or "recording"
        if base in ("metrics.json", "recordings.csv"):
            base = "_" + base
        name, n = base, 2
        while name in names:
            name, n = f"{base}_{n}", n + 1
        names.append(name)
    return names


# --------------------------------------------------------------------------------------------------
# the Ray task
# --------------------------------------------------------------------------------------------------
def replay_task(replay_one: Callable[[Any], int], args: Any, source: str, tag: str = "") -> dict[str, Any]:
    """One recording in a worker process: ``replay_one(args)`` with ``args.source = source`` and a private
    output folder; returns ``{"status", "rc", "error", "seconds", "metrics", "files"}`` where ``files``
    maps each written file (relative path) to its bytes. Errors become the one-line ``error``. The
    private folder is removed on return (``tag`` names it, so the driver can remove a killed worker's)."""
    import copy

    tmp = Path(tempfile.mkdtemp(prefix=f"deepbbs-fleet-{tag}-"))
    t0 = time.perf_counter()
    args = copy.copy(args)
    args.source, args.out, args.quiet = source, str(tmp), True
    error = ""
    try:
        with redirect_stdout(io.StringIO()), redirect_stderr(io.StringIO()):
            try:
                rc = int(replay_one(args) or 0)
            except DeepBBSError as err:
                rc, error = 1, str(err)
            except Exception as err:  # noqa: BLE001 - one recording's bug must not stop the fleet
                rc, error = 1, f"{type(err).__name__}: {err}"
        runs = [p for p in tmp.iterdir() if p.is_dir() and not p.is_symlink()]
        files: dict[str, bytes] = {}
        doc = None
        if runs:
            run = runs[0]
            files = {str(p.relative_to(run)): p.read_bytes() for p in sorted(run.rglob("*")) if p.is_file()}
            if "metrics.json" in files:
                doc = json.loads(files["metrics.json"])
        if rc != 0 and not error:
            errs = (doc or {}).get("errors") or []
            error = errs[-1] if errs else f"exit code {rc}"
        status = "ok" if rc == 0 else ("incomplete" if doc is not None else "failed")
        return {"status": status, "rc": rc, "error": error.splitlines()[0] if error else "",
                "seconds": time.perf_counter() - t0, "metrics": doc, "files": files}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------------------------------
# pooled figures
# --------------------------------------------------------------------------------------------------
def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and v is not None and math.isfinite(v) else float("nan")


def _wmean(values: list[float], weights: list[float]) -> float | None:
    pairs = [(v, w) for v, w in zip(values, weights) if math.isfinite(v) and w > 0]
    total = sum(w for _, w in pairs)
    return sum(v * w for v, w in pairs) / total if total else None


def _wrms(values: list[float], weights: list[float]) -> float | None:
    m = _wmean([v * v for v in values], weights)
    return math.sqrt(m) if m is not None else None


def _max(values: list[float]) -> float | None:
    vals = [v for v in values if math.isfinite(v)]
    return max(vals) if vals else None


def pool_metrics(mode: str, per_recording: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Pooled figures per method from the per-recording ``metrics.json["methods"]`` of every recording
    that has one (a failed recording has none and adds nothing).

    Pairs mode, weights = each recording's scored registrations (registrations less failed ones): mean
    errors and runtime are weighted means, RMSE the weighted root mean square, max the max; success rate
    weighted by registrations (a failed registration is a miss, as in one recording). Odometry: KITTI drift
    weighted by segments (the mean over every segment of the fleet), ATE RMSE over every frame of the
    fleet (each recording aligned on its own), RPE and runtime weighted by registered frames (frames - 1),
    fps = 1000 / pooled mean runtime. Localization: counts summed, shares over every scan of the fleet, the mean
    time to first pose over the recordings, tracking latency weighted by scans. Percentiles need the individual
    values and are not pooled.
    """
    names: list[str] = []
    for mm in per_recording:
        names += [n for n in mm if n not in names]
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        ms = [mm[name] for mm in per_recording if name in mm]
        if mode == "pairs":
            reg = [float(m.get("registrations", 0) or 0) for m in ms]
            scored = [r - float(m.get("failed", 0) or 0) for r, m in zip(reg, ms)]

            def err(key, m_list=ms, w=scored):
                return {"mean": _wmean([_num(m[key]["mean"]) for m in m_list], w),
                        "rmse": _wrms([_num(m[key]["rmse"]) for m in m_list], w),
                        "max": _max([_num(m[key]["max"]) for m in m_list])}

            out[name] = {
                "recordings": len(ms), "pairs": sum(int(m.get("pairs", 0) or 0) for m in ms),
                "registrations": int(sum(reg)), "failed": sum(int(m.get("failed", 0) or 0) for m in ms),
                "rot_err_deg": err("rot_err_deg"), "trans_err_m": err("trans_err_m"),
                "success_rate": _wmean([_num(m.get("success_rate")) for m in ms], reg),
                "runtime_ms": {"mean": _wmean([_num(m["runtime_ms"]["mean"]) for m in ms], scored)},
            }
        elif mode == "localization":
            scans = [float(m.get("scans", 0) or 0) for m in ms]
            total = sum(scans)

            def count(key, m_list=ms):
                vals = [m.get(key) for m in m_list]
                return None if any(v is None for v in vals) else int(sum(vals))

            placed, correct = count("placed"), count("correct")
            out[name] = {
                "recordings": len(ms), "scans": int(total), "placed": placed, "correct": correct,
                "placed_share": placed / total if total and placed is not None else None,
                "correct_share": correct / total if total and correct is not None else None,
                "wrong_published": count("wrong_published"), "recoveries": count("recoveries"),
                "time_to_first_pose_ms": {"mean": _wmean([_num(m.get("time_to_first_pose_ms")) for m in ms],
                                                         [1.0] * len(ms))},
                "latency_tracking_ms": {"mean": _wmean([_num(_get(m, "latency_tracking_ms.mean")) for m in ms],
                                                       scans)},
            }
        else:
            frames = [float(m.get("frames", 0) or 0) for m in ms]
            reg = [max(0.0, f - 1) for f in frames]
            segs = [float(m.get("kitti_segments", 0) or 0) for m in ms]
            rt = _wmean([_num(m["runtime_ms"]["mean"]) for m in ms], reg)
            out[name] = {
                "recordings": len(ms), "frames": int(sum(frames)), "kitti_segments": int(sum(segs)),
                "kitti_t_err_pct": _wmean([_num(m.get("kitti_t_err_pct")) for m in ms], segs),
                "kitti_r_err_deg_per_100m": _wmean([_num(m.get("kitti_r_err_deg_per_100m")) for m in ms], segs),
                "ate_rmse_m": _wrms([_num(m.get("ate_rmse_m")) for m in ms], frames),
                "rpe_trans_m": {"mean": _wmean([_num(m["rpe_trans_m"]["mean"]) for m in ms], reg)},
                "rpe_rot_deg": {"mean": _wmean([_num(m["rpe_rot_deg"]["mean"]) for m in ms], reg)},
                "runtime_ms": {"mean": rt},
                "fps": 1000.0 / rt if rt else None,
                "failed_frames": sum(int(m.get("failed_frames", 0) or 0) for m in ms),
            }
    return out


# --------------------------------------------------------------------------------------------------
# the driver
# --------------------------------------------------------------------------------------------------
@dataclass
class Recording:
    """One row of the fleet summary."""

    name: str
    source: str
    status: str = "not run"  # ok | incomplete (partial results written) | failed | not run
    error: str = ""
    seconds: float | None = None
    frames_read: int | None = None
    methods: dict[str, Any] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        return {"name": self.name, "source": self.source, "status": self.status, "error": self.error,
                "seconds": self.seconds, "frames_read": self.frames_read,
                "metrics": f"{self.name}/metrics.json" if self.status in ("ok", "incomplete") else None,
                "methods": self.methods}


@dataclass
class FleetResult:
    mode: str
    recordings: list[Recording]
    workers: int
    address: str
    wall_s: float = 0.0
    complete: bool = True
    errors: list[str] = field(default_factory=list)

    @property
    def pooled(self) -> dict[str, dict[str, Any]]:
        return pool_metrics(self.mode, [r.methods for r in self.recordings if r.methods])


def init_ray(workers: int | None, address: str | None) -> tuple[bool, int]:
    """Join ``address``, or start Ray in this process with ``workers`` CPUs; reuse a Ray already started
    by the caller. Quiet: no dashboard, worker output not forwarded. Returns (we started it, CPUs)."""
    try:
        import ray
    except ImportError as err:  # pragma: no cover - ray is an install requirement
        raise ConfigError("fleet runs need Ray: pip install ray") from err
    started = False
    if address:
        _check_reachable(address)
    if not ray.is_initialized():
        kw: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                              "logging_level": logging.ERROR, "configure_logging": True}
        try:
            if address:
                ray.init(address=address, **kw)
            else:
                ray.init(num_cpus=workers, **kw)
        except (ConnectionError, RuntimeError, ValueError) as err:
            where = f"the Ray cluster at {address}" if address else "a local Ray"
            raise ConfigError(f"--ray-address: cannot start or join {where} ({str(err).splitlines()[0]})") from err
        started = True
    cpus = int(ray.cluster_resources().get("CPU", 1))
    return started, cpus


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A quick TCP connect to ``HOST:PORT`` (Ray itself retries an unreachable address for minutes)."""
    import socket

    if address == "auto":
        return
    host, sep, port = address.split("://", 1)[-1].rpartition(":")
    if not sep or not port.isdigit():
        raise ConfigError(f"--ray-address: expected HOST:PORT or 'auto', got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise ConfigError(f"--ray-address: cannot reach the Ray cluster at {address} ({err.strerror or err})") from err


def run_fleet(replay_one: Callable[[Any], int], args: Any, sources: list[str], run_dir: Path, *,
              workers: int | None = None, address: str | None = None, retries: int = 3, cpus_per_task: int = 1,
              gpus_per_task: float = 0.0,
              progress: bool = True, on_result: Callable[[Recording], None] | None = None) -> FleetResult:
    """Replay every source as a Ray task (``cpus_per_task`` CPUs, ``gpus_per_task`` GPUs each) and write each
    recording's files into ``run_dir/<name>/`` as they arrive. ``on_result`` is called after each recording."""
    import ray
    from tqdm import tqdm

    names = recording_names(sources)
    recs = [Recording(n, s) for n, s in zip(names, sources)]
    started, cpus = init_ray(workers, address)
    t0 = time.perf_counter()
    res = FleetResult(getattr(args, "mode", "pairs"), recs, cpus, address or "local")
    bar = tqdm(total=len(recs), unit="recordings", desc=f"fleet {res.mode}", disable=not progress,
               dynamic_ncols=True)
    pending: dict[Any, int] = {}
    frames = failed = 0
    tag = "none"
    try:
        task = ray.remote(num_cpus=cpus_per_task, num_gpus=gpus_per_task, max_retries=retries)(replay_task)
        fn_ref, args_ref = ray.put(replay_one), ray.put(args)
        tag = f"{os.getpid()}-{int(time.time() * 1000) % 10**8}"  # the driver's pid first: one run's folders
        pending = {task.remote(fn_ref, args_ref, r.source, tag): i for i, r in enumerate(recs)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)  # Ctrl-C is seen between waits
            for ref in ready:
                rec = recs[pending.pop(ref)]
                try:
                    out = ray.get(ref)
                except ray.exceptions.RayError as err:  # the worker died more than ``retries`` times, ...
                    lines = [ln for ln in str(err).splitlines() if ln.strip()]
                    out = {"status": "failed", "error": f"{type(err).__name__}: {lines[-1] if lines else err}",
                           "seconds": None, "metrics": None, "files": {}}
                _store(run_dir / rec.name, rec, out)
                del out
                frames += rec.frames_read or 0
                failed += rec.status != "ok"
                bar.set_postfix(frames=frames, failed=failed, refresh=False)
                bar.update(1)
                if on_result:
                    on_result(rec)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        res.complete = False
        res.errors.append("interrupted by the user (Ctrl-C)")
    finally:
        bar.close()
        if started:
            ray.shutdown()
        for d in Path(tempfile.gettempdir()).glob(f"deepbbs-fleet-{tag}-*"):  # of workers killed on this machine
            shutil.rmtree(d, ignore_errors=True)
    res.wall_s = time.perf_counter() - t0
    for r in recs:
        if r.status != "ok":
            res.complete = False
            if r.status != "not run":
                res.errors.append(f"{r.name}: {r.error}")
    return res


def _store(folder: Path, rec: Recording, out: dict[str, Any]) -> None:
    """Write a task's files, then fill its row (a Ctrl-C while writing leaves the row 'not run')."""
    for rel, data in (out.get("files") or {}).items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    doc = out.get("metrics")
    if doc is not None:
        rec.frames_read = doc.get("frames_read")
        rec.methods = doc.get("methods") or {}
    rec.status, rec.error, rec.seconds = out["status"], out.get("error", ""), out.get("seconds")


# --------------------------------------------------------------------------------------------------
# outputs
# --------------------------------------------------------------------------------------------------
def write_summary(run_dir: Path, res: FleetResult, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """``metrics.json`` (the fleet summary) and ``recordings.csv`` at the top of ``run_dir``."""
    from deepbbs_ros.replay.report import _clean

    frames = sum(r.frames_read or 0 for r in res.recordings)
    doc = _clean({
        "version": __version__, "kind": "fleet", "mode": res.mode, "complete": res.complete,
        "errors": res.errors, "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "ray_address": res.address, "cpus": res.workers, "wall_s": round(res.wall_s, 3),
        "recordings_total": len(res.recordings),
        "recordings_ok": sum(r.status == "ok" for r in res.recordings),
        "frames_read": frames, "frames_per_s": frames / res.wall_s if res.wall_s > 0 else None,
        **(extra or {}),
        "recordings": [r.row() for r in res.recordings],
        "pooled": res.pooled,
    })
    (run_dir / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
    methods = list(doc["pooled"])
    keys = {"pairs": ("success_rate", "rot_err_deg.mean", "trans_err_m.mean", "runtime_ms.mean"),
            "localization": ("correct_share", "wrong_published", "time_to_first_pose_ms", "latency_tracking_ms.p50")
            }.get(res.mode, ("kitti_t_err_pct", "ate_rmse_m", "rpe_trans_m.mean", "fps"))
    with open(run_dir / "recordings.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["recording", "source", "status", "frames_read", "seconds"]
                   + [f"{m}_{k.replace('.', '_')}" for m in methods for k in keys] + ["error"])
        for r in doc["recordings"]:
            vals = [_get(r["methods"].get(m, {}), k) for m in methods for k in keys]
            w.writerow([r["name"], r["source"], r["status"], r["frames_read"], _f(r["seconds"], 2)]
                       + [_f(v, 6) for v in vals] + [r["error"]])
    return doc


def _get(d: dict, dotted: str) -> Any:
    for k in dotted.split("."):
        d = d.get(k) if isinstance(d, dict) else None
    return d


def _f(v: Any, digits: int) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def print_summary(doc: dict[str, Any], console: Any = None) -> None:
    """The per-recording table, then the pooled figures per method."""
    from rich.console import Console
    from rich.table import Table

    from deepbbs_ros.replay.report import _fmt

    console = console or Console()
    mode, pooled = doc["mode"], doc["pooled"]
    methods = list(pooled)
    flag = "" if doc["complete"] else " (INCOMPLETE)"
    t = Table(title=f"deepbbs-replay fleet {mode}: {doc['recordings_ok']}/{doc['recordings_total']} recordings{flag}")
    for col in ("recording", "status", "frames", "s"):
        t.add_column(col, justify="left" if col in ("recording", "status") else "right")
    cells = {"pairs": (("success %", lambda m: None if m.get("success_rate") is None else 100 * m["success_rate"], 1),
                       ("rot deg", lambda m: _get(m, "rot_err_deg.mean"), 3)),
             "localization": (("correct %", lambda m: None if m.get("correct_share") is None
                               else 100 * m["correct_share"], 1),
                              ("wrong", lambda m: m.get("wrong_published"), 0))
             }.get(mode, (("drift %", lambda m: m.get("kitti_t_err_pct"), 3),
                          ("ATE m", lambda m: m.get("ate_rmse_m"), 3)))
    for m in methods:
        for label, _, _ in cells:
            t.add_column(f"{m} {label}", justify="right")
    for r in doc["recordings"]:
        vals = [_fmt(fn(r["methods"][m]) if m in r["methods"] else None, d) for m in methods for _, fn, d in cells]
        t.add_row(r["name"], r["status"], _fmt(r["frames_read"]), _fmt(r["seconds"], 1), *vals)
    console.print(t)
    for r in doc["recordings"]:
        if r["error"]:
            console.print(f"  {r['name']}: {r['status']}: {r['error']}", markup=False, highlight=False)
    p = Table(title=f"pooled over the fleet ({mode})")
    p.add_column("metric")
    p.add_column("unit")
    for m in methods:
        p.add_column(m, justify="right")
    rows = ([("recordings", "count", "recordings", 0), ("pairs", "count", "pairs", 0),
             ("rotation error mean", "deg", "rot_err_deg.mean", 3),
             ("rotation error RMSE", "deg", "rot_err_deg.rmse", 3),
             ("rotation error max", "deg", "rot_err_deg.max", 3),
             ("translation error mean", "m", "trans_err_m.mean", 3),
             ("translation error RMSE", "m", "trans_err_m.rmse", 3),
             ("translation error max", "m", "trans_err_m.max", 3),
             ("success rate", "%", "success_rate", 1), ("runtime mean", "ms/pair", "runtime_ms.mean", 1)]
            if mode == "pairs" else
            [("recordings", "count", "recordings", 0), ("scans", "count", "scans", 0),
             ("placed (pose published)", "%", "placed_share", 1), ("placed within tolerance", "%", "correct_share", 1),
             ("wrong poses published", "count", "wrong_published", 0), ("recoveries", "count", "recoveries", 0),
             ("time to first pose mean", "ms", "time_to_first_pose_ms.mean", 1),
             ("latency tracking mean", "ms/scan", "latency_tracking_ms.mean", 1)]
            if mode == "localization" else
            [("recordings", "count", "recordings", 0), ("frames", "count", "frames", 0),
             ("KITTI translation drift", "%", "kitti_t_err_pct", 3),
             ("KITTI rotation drift", "deg/100 m", "kitti_r_err_deg_per_100m", 3),
             ("ATE RMSE", "m", "ate_rmse_m", 3), ("RPE translation mean", "m/frame", "rpe_trans_m.mean", 4),
             ("RPE rotation mean", "deg/frame", "rpe_rot_deg.mean", 4),
             ("runtime mean", "ms/frame", "runtime_ms.mean", 1), ("throughput", "frames/s", "fps", 1)])
    for label, unit, key, digits in rows:
        vals = []
        for m in methods:
            v = _get(pooled[m], key)
            if key in ("success_rate", "placed_share", "correct_share") and v is not None:
                v = 100 * v
            vals.append(_fmt(v, digits) if digits else _fmt(v))
        p.add_row(label, unit, *vals)
    console.print(p)
    fps = doc.get("frames_per_s")
    console.print(f"wall time {doc['wall_s']:.1f} s on {doc['cpus']} CPU(s) ({doc['ray_address']}), "
                  f"{doc['frames_read']} frames read" + (f", {fps:.1f} frames/s" if fps else ""),
                  markup=False, highlight=False)
    sys.stdout.flush()
