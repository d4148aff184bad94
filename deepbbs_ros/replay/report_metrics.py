"""The figures of ``metrics.json`` per method (pairs, odometry, localization) and what each one is; ``_clean``
makes them strict JSON. Written by :mod:`deepbbs_ros.replay.report`."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.config import Config
from deepbbs_ros.replay.runner import LocalizationResults, OdometryResults, PairResults


def _clean(obj: Any) -> Any:
    """NaN/inf -> None, numpy scalars -> Python, recursively (strict JSON)."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj



#: what each odometry figure of metrics.json is; evo on ``traj/ground_truth.tum`` (gt) and ``traj/<method>.tum``
#: (est) gives the same figures (its mean, rmse, median and max)
ODOMETRY_DEFINITIONS = {
    "ate_rmse_m": "ATE: RMSE of the position errors after SE(3) Umeyama alignment of the estimated positions onto "
                  "the ground truth (rotation + translation, no scale), m (= ate_se3_m.rmse; evo_ape tum gt est -a)",
    "ate_se3_m": "the same per-frame position errors after SE(3) Umeyama alignment, m (evo_ape tum gt est -a)",
    "ape_rot_deg": "absolute rotation error, the angle of gt_k^-1 est_k without alignment (each trajectory starts at "
                   "the first ground-truth pose), deg (evo_ape tum gt est --pose_relation angle_deg)",
    "rpe_trans_m": "RPE translation between consecutive frames (delta 1 frame), ||t((gt_{k-1}^-1 gt_k)^-1 "
                   "(est_{k-1}^-1 est_k))||, m per frame (evo_rpe tum gt est, i.e. --delta 1 --delta_unit f)",
    "rpe_rot_deg": "RPE rotation between consecutive frames (delta 1 frame), the angle of the same relative error, "
                   "deg per frame (evo_rpe tum gt est --pose_relation angle_deg)",
    "kitti_t_err_pct": "KITTI drift: translation error over path segments of 100-800 m starting every 10 frames, "
                       "% (the KITTI odometry devkit)",
    "kitti_r_err_deg_per_100m": "KITTI drift: rotation error over the same segments, deg per 100 m",
    "rotation angle": "atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2), exact at every angle (scipy's "
                      "Rotation.magnitude, which evo uses); ground-truth rotations are projected onto SO(3) when read",
}
#: what each pairs-mode figure is
PAIR_DEFINITIONS = {
    "rot_err_deg": "rotation error of a pair, the angle of R_gt^T R_est, deg (ground truth projected onto SO(3) "
                   "when read; the angle as atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2))",
    "trans_err_m": "translation error of a pair, ||t_est - t_gt||, m",
}


def pair_metrics(res: PairResults, config: Config) -> dict[str, dict[str, Any]]:
    ev = config.eval
    out = {}
    for name in res.methods:
        recs = res.of(name)
        rot = np.array([r.rot_err_deg for r in recs], dtype=np.float64)
        tr = np.array([r.trans_err_m for r in recs], dtype=np.float64)
        out[name] = {
            "pairs": len({r.pair for r in recs}),
            "registrations": len(recs),
            "rot_err_deg": metrics.summarize(rot),
            "trans_err_m": metrics.summarize(tr),
            "success_rate": metrics.success_rate(rot, tr, ev.success_rot_deg, ev.success_trans),
            "runtime_ms": metrics.runtime_summary([r.runtime_ms for r in recs]),
            "failed": sum(1 for r in recs if r.error),
            "input": res.inputs.get(name, ""),
        }
        judged = [r for r in recs if r.valid is not None]
        if judged:  # the method's verdict: poses it accepted / rejected
            out[name]["accepted"] = sum(1 for r in judged if r.valid)
            out[name]["rejected"] = sum(1 for r in judged if not r.valid)
    return out


def odometry_metrics(res: OdometryResults) -> dict[str, dict[str, Any]]:
    out = {}
    n = res.frames
    gt = np.stack(res.T_world_gt[:n]) if res.has_ground_truth else None
    for name in res.methods:
        est = np.stack(res.T_world_est[name][:n]) if n else np.zeros((0, 4, 4))
        rt = np.asarray(res.runtime_ms[name][1:n], dtype=np.float64)  # frame 0 has no registration
        m: dict[str, Any] = {"frames": n, "runtime_ms": metrics.runtime_summary(rt)}
        mean_rt = m["runtime_ms"]["mean"]
        m["fps"] = 1000.0 / mean_rt if mean_rt and math.isfinite(mean_rt) else float("nan")
        nan_summary = metrics.summarize([])
        if gt is not None and n >= 2:
            drift = metrics.kitti_drift(est, gt)
            rpe_t, rpe_r = metrics.rpe(est, gt)
            ate = metrics.ate_errors(est, gt)
            m.update(kitti_t_err_pct=drift["t_err_pct"], kitti_r_err_deg_per_100m=drift["r_err_deg_per_100m"],
                     kitti_segments=drift["segments"], ate_rmse_m=float(np.sqrt(np.mean(ate**2))),
                     ate_se3_m=metrics.summarize(ate), ape_rot_deg=metrics.summarize(metrics.ape_rotation_deg(est, gt)),
                     rpe_trans_m=metrics.summarize(rpe_t), rpe_rot_deg=metrics.summarize(rpe_r),
                     path_length_m=float(metrics.trajectory_distances(gt)[-1]))
        else:
            m.update(kitti_t_err_pct=float("nan"), kitti_r_err_deg_per_100m=float("nan"), kitti_segments=0,
                     ate_rmse_m=float("nan"), ate_se3_m=nan_summary, ape_rot_deg=nan_summary,
                     rpe_trans_m=nan_summary, rpe_rot_deg=nan_summary, path_length_m=float("nan"))
        m["failed_frames"] = len(res.failed.get(name, []))
        m["input"] = res.inputs.get(name, "")
        out[name] = m
    return out


#: what each localization figure of metrics.json is (``eval.success_rot_deg`` / ``success_trans`` the tolerance)
LOCALIZATION_DEFINITIONS = {
    "placed_share": "share of the scans given a pose the verdict accepted (a published pose)",
    "correct_share": "share of the scans given a published pose within eval.success_rot_deg and eval.success_trans "
                     "of the ground truth (the recording's ground truth is taken to be in the map frame)",
    "wrong_published": "published poses (accepted by the verdict) outside that tolerance: wrong poses a robot "
                       "would have used",
    "rejected": "scans without a published pose (searching, ambiguous, rejected by the verdict, lost)",
    "time_to_first_pose_ms": "the tracker's compute time from the first scan until its first published pose "
                             "(every scan before it included), ms; first_pose_scans: how many scans that took",
    "time_to_first_pose_s": "recording time from the first scan's stamp to the first published pose's, s",
    "lost": "times the tracker declared itself lost; recoveries: times it was lost and found again",
    "rot_err_deg": "rotation error of the published poses, the angle of R_gt^T R_est, deg",
    "trans_err_m": "translation error of the published poses, ||t_est - t_gt||, m",
    "latency_global_ms": "the tracker's time per scan when it searched the map (mode global), ms",
    "latency_tracking_ms": "the tracker's time per scan when it tracked from its prediction (mode tracking), ms",
    "setup_ms": "building the localizer for the map (candidate places, descriptors), ms",
}


def localization_metrics(res: LocalizationResults, config: Config) -> dict[str, dict[str, Any]]:
    """The figures of one localization run (see :data:`LOCALIZATION_DEFINITIONS`), under the method name
    ``deepbbs++``."""
    ev = config.eval
    recs = res.records
    n = len(recs)
    valid = np.array([r.valid for r in recs], dtype=bool)
    rot = np.array([r.rot_err_deg for r in recs], dtype=np.float64)
    tr = np.array([r.trans_err_m for r in recs], dtype=np.float64)
    ms = np.array([r.time_ms for r in recs], dtype=np.float64)
    gt = res.has_ground_truth
    ok = valid & (rot <= ev.success_rot_deg) & (tr <= ev.success_trans)
    events: dict[str, int] = {}
    for r in recs:
        events[r.event] = events.get(r.event, 0) + 1
    first = int(np.argmax(valid)) if valid.any() else None
    share = (lambda k: k / n) if n else (lambda k: float("nan"))
    m: dict[str, Any] = {
        "scans": n,
        "placed": int(valid.sum()),
        "placed_share": share(int(valid.sum())),
        "correct": int(ok.sum()) if gt else None,
        "correct_share": share(int(ok.sum())) if gt else None,
        "wrong_published": int((valid & ~ok).sum()) if gt else None,
        "rejected": int((~valid).sum()),
        "events": events,
        "first_pose_scans": None if first is None else first + 1,
        "time_to_first_pose_ms": None if first is None else float(np.nansum(ms[: first + 1])),
        "time_to_first_pose_s": None if first is None else (recs[first].stamp_ns - recs[0].stamp_ns) * 1e-9,
        "lost": events.get("lost", 0),
        "recoveries": res.recoveries,
        "rot_err_deg": metrics.summarize(rot[valid]),
        "trans_err_m": metrics.summarize(tr[valid]),
        "latency_global_ms": metrics.runtime_summary([r.time_ms for r in recs if r.mode == "global"]),
        "latency_tracking_ms": metrics.runtime_summary([r.time_ms for r in recs if r.mode == "tracking"]),
        "latency_ms": metrics.runtime_summary(ms),
        "setup_ms": res.setup_ms,
        "map_points": res.map_points,
        "places": 0 if res.places is None else len(res.places),
        "input": "the raw scan against the prior map (MapTracker: global search, then tracking)",
    }
    return {"deepbbs++": m}

