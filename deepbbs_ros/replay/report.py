"""Replay outputs: metrics.json (the machine-readable contract), CSV, TUM/KITTI trajectories, the config
used, the results bag and the terminal table, one module each (``report_metrics``, ``report_files``,
``report_bag``, ``report_table``; every name imported from here too). Plots live in :mod:`deepbbs_ros.replay.plots`.

``metrics.json``::

    {"version", "source", "mode", "complete", "errors", "created", "frames_read", "protocol", ...,
     "methods": {<method>: {
        pairs mode:    "pairs", "rot_err_deg" {mean rmse median p95 max}, "trans_err_m" {...},
                       "success_rate", "runtime_ms" {mean p50 p95}, "input"
        odometry mode: "frames", "kitti_t_err_pct", "kitti_r_err_deg_per_100m", "kitti_segments",
                       "ate_rmse_m", "ate_se3_m" {...}, "ape_rot_deg" {...}, "rpe_trans_m" {...},
                       "rpe_rot_deg" {...}, "runtime_ms" {...}, "fps", "failed_frames", "input"
        localization mode (method "deepbbs++"): "scans", "placed", "placed_share", "correct",
                       "correct_share", "wrong_published", "rejected", "events" {...}, "time_to_first_pose_ms",
                       "first_pose_scans", "time_to_first_pose_s", "lost", "recoveries", "rot_err_deg" {...},
                       "trans_err_m" {...}, "latency_global_ms" {mean p50 p95}, "latency_tracking_ms" {...},
                       "latency_ms" {...}, "setup_ms", "map_points", "places"}},
     "definitions": {<metric key>: what it is, with the evo command that gives the same figures}}

The odometry figures are evo's on the trajectories in traj/ (:data:`ODOMETRY_DEFINITIONS`). Numbers that
cannot be computed (no ground truth, path shorter than 100 m) are ``null``.
"""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path

from deepbbs_ros import __version__, cpu_kernels, metrics
from deepbbs_ros.config import Config
from deepbbs_ros.replay.report_bag import BAG_MAP_POINTS, write_results_bag
from deepbbs_ros.replay.report_files import (
    write_localization_csv,
    write_localization_trajectories,
    write_odometry_csv,
    write_pairs_csv,
    write_trajectories,
)
from deepbbs_ros.replay.report_metrics import (
    LOCALIZATION_DEFINITIONS,
    ODOMETRY_DEFINITIONS,
    PAIR_DEFINITIONS,
    _clean,
    localization_metrics,
    odometry_metrics,
    pair_metrics,
)
from deepbbs_ros.replay.report_table import (
    LOCALIZATION_TRUTH_ROWS,
    NO_VERDICT,
    _fmt,
    _get,
    print_table,
    table_definitions,
    table_notes,
    table_rows,
)
from deepbbs_ros.replay.runner import LocalizationResults, OdometryResults, PairResults

__all__ = [  # the parts live in report_metrics, report_files, report_bag and report_table; imported from here
    "BAG_MAP_POINTS", "LOCALIZATION_DEFINITIONS", "LOCALIZATION_TRUTH_ROWS", "NO_VERDICT", "ODOMETRY_DEFINITIONS",
    "PAIR_DEFINITIONS", "_clean", "_fmt", "_get", "localization_metrics", "make_run_dir", "odometry_metrics",
    "pair_metrics", "print_table", "table_definitions", "table_notes", "table_rows", "write_localization_csv",
    "write_localization_trajectories", "write_metrics_json", "write_odometry_csv", "write_pairs_csv",
    "write_results_bag", "write_trajectories",
]


def make_run_dir(out: str | Path) -> Path:
    """``OUT/<YYYY-mm-dd_HH-MM-SS>/`` (suffixed if taken) and ``OUT/latest`` -> it."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    run = out / stamp
    n = 1
    while run.exists():
        run = out / f"{stamp}_{n}"
        n += 1
    run.mkdir()
    latest = out / "latest"
    if latest.is_symlink() or latest.exists():
        latest.unlink()
    try:
        latest.symlink_to(run.name, target_is_directory=True)
    except OSError:  # filesystems without symlinks: a text file naming the folder
        latest.write_text(run.name + "\n")
    return run


def write_metrics_json(path: Path, *, source: str, mode: str,
                       res: PairResults | OdometryResults | LocalizationResults, config: Config, method_metrics: dict,
                       extra: dict | None = None) -> dict:
    ev = config.eval
    if mode == "pairs":
        protocol = {"stride": ev.stride, "max_dist_m": ev.max_dist, "max_pair_frames": ev.max_pair_frames,
                    "perturb_yaw_deg": ev.perturb_yaw_deg, "perturb_trans_m": ev.perturb_trans, "trials": ev.trials,
                    "seed": ev.seed, "success_rot_deg": ev.success_rot_deg, "success_trans_m": ev.success_trans}
        definitions = PAIR_DEFINITIONS
    elif mode == "localization":
        protocol = {"stride": ev.odom_stride, "initial_pose": "none (global search)",
                    "success_rot_deg": ev.success_rot_deg, "success_trans_m": ev.success_trans}
        definitions = LOCALIZATION_DEFINITIONS
    else:
        protocol = {"stride": ev.odom_stride, "init": ev.odom_init, "kitti_lengths_m": list(metrics.KITTI_LENGTHS),
                    "kitti_step_frames": metrics.KITTI_STEP}
        definitions = ODOMETRY_DEFINITIONS
    doc = {
        "version": __version__,
        "cpu_kernels": cpu_kernels.state(),  # the same figures on any x86-64 computer with AVX2 when "avx2"
        "source": source,
        "mode": mode,
        "complete": bool(res.complete),
        "errors": list(res.errors),
        "created": _dt.datetime.now().isoformat(timespec="seconds"),
        "frames_read": res.frames_read,
        "protocol": protocol,
        **(extra or {}),
        "methods": method_metrics,
        "definitions": definitions,
    }
    doc = _clean(doc)
    path.write_text(json.dumps(doc, indent=2) + "\n")
    return doc
