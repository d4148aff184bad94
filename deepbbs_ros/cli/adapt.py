"""``deepbbs-train adapt``: read, split, pseudo-label, fine-tune, report (deepbbs_ros/train/adapt.py does the work)."""

from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

from deepbbs_ros.cli.train_parser import _config, _overrides
from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError

# what a resume takes from the saved command (the rest, e.g. the time budget, may change)
KEPT = ("recording", "topic", "every", "max_frames", "held_back", "gap", "strides", "cycle_rot_deg", "cycle_trans",
        "steps", "lr", "eval_stride", "eval_max_dist", "perturb_yaw", "perturb_trans", "trials", "config", "set")


def _strides(text: str) -> list[int]:
    try:
        out = sorted({int(s) for s in text.split(",") if s.strip()})
    except ValueError as err:
        raise ConfigError(f"--strides: expected integers like '1,2,4', got {text!r}") from err
    if not out or out[0] < 1:
        raise ConfigError(f"--strides: expected positive integers like '1,2,4', got {text!r}")
    return out


def run_adapt(args, cfg: Config) -> int:
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.train import adapt as A
    from deepbbs_ros.train.adapt_report import evaluate_held, held_pairs, markdown
    from deepbbs_ros.train.pseudo import Labels, split_frames

    out = Path(args.out)
    A.check_out(out, args.resume)
    saved = out / "adapt_args.json"
    if args.resume and saved.exists():
        prev = json.loads(saved.read_text())
        for k in KEPT:
            setattr(args, k, prev.get(k, getattr(args, k)))
        cfg = _config(args)
    else:
        saved.write_text(json.dumps({**{k: getattr(args, k) for k in KEPT},
                                     "command": "deepbbs-train " + shlex.join(sys.argv[1:])}, indent=2))
    cfg = cfg.replace(**{"train.lr": args.lr})
    strides = _strides(args.strides)
    progress = not args.no_progress
    weights = cfg.registration.weights
    t0 = time.perf_counter()
    reg = DeepBBSRegistration(cfg, weights=weights or None, device=args.device)
    try:
        rec = A.read_recording(args.recording, reg, topic=args.topic, every=args.every, max_frames=args.max_frames,
                               progress=progress)
        frames, held = split_frames(len(rec), args.held_back, args.gap)
        read_s = time.perf_counter() - t0
        labels_path, summary_path = out / A.LABELS_FILE, out / "labels.json"
        if args.resume and labels_path.exists() and summary_path.exists():
            labels, summary = Labels.load(labels_path), json.loads(summary_path.read_text())
        else:
            t1 = time.perf_counter()
            labels, counts = A.make_labels(rec, reg, frames, strides, args.cycle_rot_deg, args.cycle_trans, progress)
            summary = {**A.label_summary(rec, labels, counts), "seconds": round(time.perf_counter() - t1, 1),
                       "read_seconds": round(read_s, 1), "scans": len(rec), "adaptation_scans": len(frames),
                       "held_back_scans": len(held)}
            labels.save(labels_path)
            A.write_json(summary_path, summary)
    finally:
        reg.close()
    print(f"deepbbs-train adapt: {len(rec)} scans ({len(frames)} to adapt on, {len(held)} held back); "
          f"{summary['accepted']} pairs accepted, {summary['kept']} kept as labels", file=sys.stderr)

    pairs = [] if rec.T_world_lidar is None or args.no_report else held_pairs(
        rec.T_world_lidar, held, args.eval_stride, args.eval_max_dist)

    def evaluate(w: str) -> dict:
        if not pairs:
            return {"pairs": 0}
        t = time.perf_counter()
        res = evaluate_held(cfg, w, rec.prepared, rec.T_world_lidar, pairs, yaw_deg=args.perturb_yaw,
                            trans_m=args.perturb_trans, trials=args.trials, seed=cfg.train.seed, device=args.device)
        return {**res, "seconds": round(time.perf_counter() - t, 1)}

    before_path = out / "before.json"
    before = json.loads(before_path.read_text()) if args.resume and before_path.exists() else evaluate(weights)
    A.write_json(before_path, before)
    meta = {"command": "deepbbs-train " + shlex.join(sys.argv[1:]), "recording": str(args.recording),
            "labels": summary.get("kept")}
    cost = A.fine_tune(cfg, out, rec, labels, steps=args.steps, resume=args.resume,
                       time_budget_min=args.time_budget_min, device=args.device, progress=progress, meta=meta,
                       train_overrides=_overrides(args.set))
    after = evaluate(str(out / A.ADAPTED_MODEL))
    A.write_json(out / "report.json", {"labels": summary, "training": cost, "before": before, "after": after})
    text = markdown(before, after, summary, cost)
    (out / "report.md").write_text(text)
    print(text)
    print(f"deepbbs-train adapt: the adapted model is {out / A.ADAPTED_MODEL} "
          f"(use it with --set registration.weights={out / A.ADAPTED_MODEL})")
    return 0
