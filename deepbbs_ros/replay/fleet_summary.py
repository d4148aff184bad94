"""A fleet run's summary: ``metrics.json`` and ``recordings.csv`` at the top of the run folder, and the tables
printed at the end (per recording, then pooled per method; see :mod:`deepbbs_ros.replay.fleet`)."""

from __future__ import annotations

import csv
import datetime as _dt
import json
import math
import sys
from pathlib import Path
from typing import Any

from deepbbs_ros import __version__
from deepbbs_ros.replay.fleet_results import FleetResult, get_dotted


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
            vals = [get_dotted(r["methods"].get(m, {}), k) for m in methods for k in keys]
            w.writerow([r["name"], r["source"], r["status"], r["frames_read"], _f(r["seconds"], 2)]
                       + [_f(v, 6) for v in vals] + [r["error"]])
    return doc


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
                       ("rot deg", lambda m: get_dotted(m, "rot_err_deg.mean"), 3)),
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
            v = get_dotted(pooled[m], key)
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
