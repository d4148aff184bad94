"""A training run's logs: ``log.jsonl`` (one JSON record per training step, ``"kind": "train"``, and per validation,
``"kind": "val"``), ``val.csv`` (the validation records as a table) and the Markdown report of a run folder; the
names of the folder's checkpoint files (written by run_state.py)."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.errors import ModelError

STATE_FILE = "state_latest.pt"  # everything an exact resume needs (run_state.save_state)
LATEST_MODEL = "model_latest.pt"  # the latest weights, in the shipped checkpoint format
BEST_MODEL = "model_best.pt"  # the best validated weights, idem


def append_log(run_dir: Path, rec: dict[str, Any]) -> None:
    """One record more in ``log.jsonl``."""
    with open(run_dir / "log.jsonl", "a") as fh:
        fh.write(json.dumps(rec) + "\n")


def truncate_log(run_dir: Path, step: int) -> None:
    """After a resume, drop log records written after the restored ``step`` (they will be redone)."""
    log = run_dir / "log.jsonl"
    if not log.exists():
        return
    keep = [ln for ln in log.read_text().splitlines() if ln.strip() and json.loads(ln).get("step", 0) <= step]
    log.write_text("".join(k + "\n" for k in keep))


def write_val_csv(run_dir: Path, history: list[dict[str, Any]]) -> None:
    """``val.csv``: the validation records of ``history``, one row each (nothing written without any)."""
    vals = [h for h in history if h.get("kind") == "val"]
    if not vals:
        return
    cols = ["step", "epoch", "val_loss"] + [f"{s}_{k}" for s in ("plain", "yaw")
                                              for k in ("rot_mean_deg", "trans_mean_m", "success")]
    with open(run_dir / "val.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for v in vals:
            w.writerow([v["step"], v["epoch"], f"{v['val_loss']:.6g}"]
                       + [f"{v[s][k]:.6g}" for s in ("plain", "yaw") for k in ("rot_mean_deg", "trans_mean_m",
                                                                                "success")])


def run_report(run_dir: str | Path) -> str:
    """Markdown: steps done, training time, seconds per step (by points per cloud), and the validation
    history of a run folder (from ``log.jsonl``)."""
    run_dir = Path(run_dir)
    log = run_dir / "log.jsonl"
    if not log.exists():
        raise ModelError(f"report: no log.jsonl in {run_dir}")
    train, vals = [], []
    for ln in log.read_text().splitlines():
        if ln.strip():
            rec = json.loads(ln)
            (vals if rec.get("kind") == "val" else train).append(rec)
    out = [f"Run `{run_dir}`: {len(train)} steps"]
    if train:
        secs = sum(r["s_per_step"] for r in train)
        out[0] += (f", {secs / 60:.1f} min of training steps ({np.median([r['s_per_step'] for r in train]):.2f} "
                   f"s/step median), {sum(v.get('seconds', 0) for v in vals) / 60:.1f} min of validation")
    out += ["", "| step | epoch | val loss | rot (deg) | trans (m) | success (%) | +yaw rot (deg) | +yaw trans (m) "
            "| +yaw success (%) |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for v in vals:
        p, y = v["plain"], v["yaw"]
        out.append(f"| {v['step']} | {v['epoch']} | {v['val_loss']:.4g} | {p['rot_mean_deg']:.3f} | "
                   f"{p['trans_mean_m']:.3f} | {100 * p['success']:.1f} | {y['rot_mean_deg']:.3f} | "
                   f"{y['trans_mean_m']:.3f} | {100 * y['success']:.1f} |")
    best = run_dir / "val_best.json"
    if best.exists():
        b = json.loads(best.read_text())
        out += ["", f"Best checkpoint `{run_dir / BEST_MODEL}`: step {b.get('step')} (epoch {b.get('epoch')}), "
                    f"saved {b.get('saved_utc')}."]
    return "\n".join(out)
