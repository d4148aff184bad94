"""Replay outputs: metrics.json (the machine-readable contract), CSV, TUM/KITTI trajectories, the config
used, the results bag and the terminal table. Plots live in :mod:`deepbbs_ros.replay.plots`.

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

import csv
import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros import __version__, cpu_kernels, metrics
from deepbbs_ros.config import Config
from deepbbs_ros.replay.methods import topic_name
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


# --------------------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------------------
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


# --------------------------------------------------------------------------------------------------
# CSV and trajectories
# --------------------------------------------------------------------------------------------------
def write_pairs_csv(path: Path, res: PairResults) -> None:
    cols = ["method", "pair", "trial", "src_index", "tgt_index", "src_stamp_ns", "tgt_stamp_ns", "gt_dist_m",
            "rot_err_deg", "trans_err_m", "success", "runtime_ms", "preprocess_ms", "converged", "valid", "score",
            "path", "init_yaw_deg", "init_trans_m"] + [
            f"T_target_source_{i}{j}" for i in range(3) for j in range(4)] + [
            f"T_gt_{i}{j}" for i in range(3) for j in range(4)] + ["error"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in res.records:
            yaw = float(np.degrees(np.arctan2(r.T_init[1, 0], r.T_init[0, 0])))
            w.writerow([r.method, r.pair, r.trial, r.src_index, r.tgt_index, r.src_stamp_ns, r.tgt_stamp_ns,
                        f"{r.gt_dist_m:.4f}", f"{r.rot_err_deg:.6g}", f"{r.trans_err_m:.6g}", int(r.success),
                        f"{r.runtime_ms:.3f}", f"{r.preprocess_ms:.3f}", int(r.converged),
                        "" if r.valid is None else int(r.valid), f"{r.score:.4f}", r.path, f"{yaw:.3f}",
                        f"{np.linalg.norm(r.T_init[:3, 3]):.4f}"]
                       + [f"{v:.9g}" for v in r.T_est[:3, :].ravel()] + [f"{v:.9g}" for v in r.T_gt[:3, :].ravel()]
                       + [r.error])


def write_odometry_csv(path: Path, res: OdometryResults) -> None:
    n = res.frames
    gt = np.stack(res.T_world_gt[:n]) if res.has_ground_truth else None
    cols = ["frame", "index", "stamp_ns"]
    for name in res.methods:
        cols += [f"{name}_x", f"{name}_y", f"{name}_z", f"{name}_runtime_ms"]
        if gt is not None:  # RPE from frame k-1 to k (empty at frame 0), ATE after SE(3) alignment, APE unaligned
            cols += [f"{name}_rpe_trans_m_per_frame", f"{name}_rpe_rot_deg_per_frame", f"{name}_ate_se3_m",
                     f"{name}_ape_rot_deg"]
    if gt is not None:
        cols += ["gt_x", "gt_y", "gt_z"]
    rpes = {}
    if gt is not None:
        for name in res.methods:
            est = np.stack(res.T_world_est[name][:n])
            t, r = metrics.rpe(est, gt)
            rpes[name] = (np.concatenate([[np.nan], t]), np.concatenate([[np.nan], r]), metrics.ate_errors(est, gt),
                          metrics.ape_rotation_deg(est, gt))
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for k in range(n):
            row = [k, res.indices[k], res.stamps_ns[k]]
            for name in res.methods:
                T = res.T_world_est[name][k]
                row += [repr(float(v)) for v in T[:3, 3]] + [f"{res.runtime_ms[name][k]:.3f}"]
                if gt is not None:
                    row += [repr(float(e[k])) if np.isfinite(e[k]) else "" for e in rpes[name]]
            if gt is not None:
                row += [repr(float(v)) for v in gt[k][:3, 3]]
            w.writerow(row)


def _yaw_deg(T: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))


def write_localization_csv(path: Path, res: LocalizationResults) -> None:
    """One row per scan: what the tracker said (event, valid, score, mode, path, candidates, time), its pose
    (x y z yaw in the map frame, empty when no pose was published), the errors against the ground truth and the
    ground truth (empty without it), and the reason when no pose."""
    cols = ["scan", "index", "stamp_ns", "event", "valid", "score", "mode", "path", "candidates", "time_ms",
            "rot_err_deg", "trans_err_m", "x", "y", "z", "yaw_deg", "gt_x", "gt_y", "gt_z", "gt_yaw_deg", "reason"]

    def num(v: float, fmt: str = "{:.6g}") -> str:
        return fmt.format(v) if np.isfinite(v) else ""

    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for k, r in enumerate(res.records):
            pose = ([repr(float(v)) for v in r.T_map_est[:3, 3]] + [f"{_yaw_deg(r.T_map_est):.4f}"]
                    if np.isfinite(r.T_map_est).all() else [""] * 4)
            gt = ([repr(float(v)) for v in r.T_map_gt[:3, 3]] + [f"{_yaw_deg(r.T_map_gt):.4f}"]
                  if r.T_map_gt is not None else [""] * 4)
            w.writerow([k, r.index, r.stamp_ns, r.event, int(r.valid), num(r.score, "{:.4f}"), r.mode, r.path,
                        r.candidates, f"{r.time_ms:.3f}", num(r.rot_err_deg), num(r.trans_err_m), *pose, *gt,
                        r.reason])


def write_localization_trajectories(run: Path, res: LocalizationResults) -> list[Path]:
    """``traj/localization.tum`` (the published poses only, map frame) and ``traj/ground_truth.tum`` (every scan)."""
    d = run / "traj"
    d.mkdir(exist_ok=True)
    placed = [r for r in res.records if r.valid]
    written = [d / "localization.tum"]
    metrics.write_tum(written[0], np.asarray([r.stamp_ns for r in placed], dtype=np.int64),
                      [r.T_map_est for r in placed])
    if res.has_ground_truth:
        written.append(d / "ground_truth.tum")
        metrics.write_tum(written[-1], np.asarray([r.stamp_ns for r in res.records], dtype=np.int64),
                          [r.T_map_gt for r in res.records])
    return written


def write_trajectories(run: Path, res: OdometryResults) -> list[Path]:
    """``traj/<method>.tum|.kitti`` and ``traj/ground_truth.tum|.kitti`` (poses of the sensor in the world)."""
    n = res.frames
    d = run / "traj"
    d.mkdir(exist_ok=True)
    stamps = np.asarray(res.stamps_ns[:n], dtype=np.int64)  # integer ns: written exactly
    written = []
    items = [(topic_name(m), res.T_world_est[m][:n]) for m in res.methods]
    if res.has_ground_truth:
        items.append(("ground_truth", res.T_world_gt[:n]))
    for stem, poses in items:
        P = np.stack(poses) if poses else np.zeros((0, 4, 4))
        metrics.write_tum(d / f"{stem}.tum", stamps, P)
        metrics.write_kitti(d / f"{stem}.kitti", P)
        written += [d / f"{stem}.tum", d / f"{stem}.kitti"]
    return written


# --------------------------------------------------------------------------------------------------
# results bag (rosbag2, mcap)
# --------------------------------------------------------------------------------------------------
#: the results bag of a localization run holds the map with at most this many points (a regular subsample)
BAG_MAP_POINTS = 1_000_000


def write_results_bag(path: Path, res: PairResults | OdometryResults | LocalizationResults, *,
                      world_frame: str = "world", map_frame: str = "map") -> dict[str, int]:
    """Write the estimates as a rosbag2 (mcap storage) that Foxglove opens.

    Pairs mode: ``/deepbbs_replay/<method>/pose`` PoseStamped (``T_target_source``, frame = target frame,
    stamp = source stamp), ``/deepbbs_replay/ground_truth/pose`` and, for the first few pairs,
    ``/deepbbs_replay/target_cloud`` and ``/deepbbs_replay/<method>/aligned_cloud`` (source points moved
    into the target frame by the estimate). Odometry mode: ``/deepbbs_replay/<method>/odometry`` and
    ``/deepbbs_replay/ground_truth/odometry`` nav_msgs/Odometry (``world_frame`` -> sensor frame).
    Localization mode: ``/deepbbs_replay/localization/pose`` PoseStamped (``T_map_scan`` in ``map_frame``, the
    published poses only), ``/deepbbs_replay/ground_truth/pose`` and the map once (``/deepbbs_replay/map``
    PointCloud2, at the first scan's stamp, at most :data:`BAG_MAP_POINTS` points).
    Returns the message count per topic.
    """
    from rosbags.typesys import Stores, get_typestore

    from deepbbs_ros.datasets.rosbag import rosbag2_writer
    from msg_adapters.pointcloud2 import arrays_to_pointcloud2
    from msg_adapters.transforms import matrix_to_odometry, matrix_to_pose_stamped

    ts = get_typestore(Stores.ROS2_JAZZY)
    counts: dict[str, int] = {}
    messages: list[tuple[int, str, str, Any]] = []  # (stamp, topic, type, msg)

    def add(stamp, topic, msgtype, msg):
        messages.append((int(stamp), topic, msgtype, msg))

    if isinstance(res, PairResults):
        seen_gt = set()
        for r in res.records:
            if r.trial != 0 or not np.isfinite(r.T_est).all():
                continue
            add(r.src_stamp_ns, f"/deepbbs_replay/{topic_name(r.method)}/pose", "geometry_msgs/msg/PoseStamped",
                matrix_to_pose_stamped(r.T_est, r.src_stamp_ns, r.frame_id, flavor="rosbags"))
            if r.pair not in seen_gt:
                seen_gt.add(r.pair)
                add(r.src_stamp_ns, "/deepbbs_replay/ground_truth/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_gt, r.src_stamp_ns, r.frame_id, flavor="rosbags"))
        for c in res.clouds:
            add(c["stamp_ns"], "/deepbbs_replay/target_cloud", "sensor_msgs/msg/PointCloud2",
                arrays_to_pointcloud2(c["target"], stamp_ns=c["stamp_ns"], frame_id=c["frame_id"], flavor="rosbags"))
            for name, T in c["T_est"].items():
                if not np.isfinite(T).all():
                    continue
                xyz = (c["source"].astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
                add(c["stamp_ns"], f"/deepbbs_replay/{topic_name(name)}/aligned_cloud", "sensor_msgs/msg/PointCloud2",
                    arrays_to_pointcloud2(xyz, stamp_ns=c["stamp_ns"], frame_id=c["frame_id"], flavor="rosbags"))
    elif isinstance(res, LocalizationResults):
        if res.map_xyz is not None and res.records:
            xyz = np.asarray(res.map_xyz)[:: max(1, -(-len(res.map_xyz) // BAG_MAP_POINTS))].astype(np.float32)
            stamp = res.records[0].stamp_ns
            add(stamp, "/deepbbs_replay/map", "sensor_msgs/msg/PointCloud2",
                arrays_to_pointcloud2(xyz, stamp_ns=stamp, frame_id=map_frame, flavor="rosbags"))
        for r in res.records:
            if r.valid and np.isfinite(r.T_map_est).all():
                add(r.stamp_ns, "/deepbbs_replay/localization/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_map_est, r.stamp_ns, map_frame, flavor="rosbags"))
            if r.T_map_gt is not None:
                add(r.stamp_ns, "/deepbbs_replay/ground_truth/pose", "geometry_msgs/msg/PoseStamped",
                    matrix_to_pose_stamped(r.T_map_gt, r.stamp_ns, map_frame, flavor="rosbags"))
    else:
        n = res.frames
        child = res.frame_id or "lidar"
        tracks = [(topic_name(m), res.T_world_est[m][:n]) for m in res.methods]
        if res.has_ground_truth:
            tracks.append(("ground_truth", res.T_world_gt[:n]))
        for stem, poses in tracks:
            for k, T in enumerate(poses):
                add(res.stamps_ns[k], f"/deepbbs_replay/{stem}/odometry", "nav_msgs/msg/Odometry",
                    matrix_to_odometry(T, res.stamps_ns[k], world_frame, child, flavor="rosbags"))

    messages.sort(key=lambda m: m[0])
    with rosbag2_writer(path, "mcap") as writer:  # zstd chunks with chunk, data and summary CRCs
        conns = {}
        for stamp, topic, msgtype, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], stamp, ts.serialize_cdr(msg, msgtype))
            counts[topic] = counts.get(topic, 0) + 1
    return counts


# --------------------------------------------------------------------------------------------------
# terminal table
# --------------------------------------------------------------------------------------------------
def _fmt(v: Any, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def _get(m: dict, key: str, stat: str) -> Any:
    """``m[key][stat]``, None when ``key`` is absent (metrics of an older metrics.json)."""
    return (m.get(key) or {}).get(stat)


#: the verdict cells of a method that gives none (baselines)
NO_VERDICT = "n/a"


def table_rows(mode: str, method_metrics: dict[str, dict]) -> tuple[list[str], list[tuple[str, str, list[str]]]]:
    """(method names, [(metric, unit, [value per method])]) of the comparison table."""
    names = list(method_metrics)
    M = method_metrics

    def col(fn, digits=3):
        return [_fmt(fn(M[n]), digits) for n in names]

    if mode == "pairs":
        rows = [
            ("pairs", "count", col(lambda m: m["pairs"])),
            ("rotation error mean (MAE)", "deg", col(lambda m: m["rot_err_deg"]["mean"])),
            ("rotation error RMSE", "deg", col(lambda m: m["rot_err_deg"]["rmse"])),
            ("rotation error p95", "deg", col(lambda m: m["rot_err_deg"]["p95"])),
            ("translation error mean (MTE)", "m", col(lambda m: m["trans_err_m"]["mean"])),
            ("translation error RMSE", "m", col(lambda m: m["trans_err_m"]["rmse"])),
            ("translation error p95", "m", col(lambda m: m["trans_err_m"]["p95"])),
            ("success rate", "%", col(lambda m: None if m["success_rate"] is None else 100 * m["success_rate"], 1)),
            ("runtime mean", "ms/pair", col(lambda m: m["runtime_ms"]["mean"], 1)),
            ("runtime p95", "ms/pair", col(lambda m: m["runtime_ms"]["p95"], 1)),
        ]
        if any(M[n].get("registrations", M[n]["pairs"]) != M[n]["pairs"] for n in names):  # --trials N
            rows.insert(1, ("registrations", "pairs x trials", col(lambda m: m.get("registrations"))))
        if any("accepted" in M[n] for n in names):  # the verdict (DeepBBS++): poses accepted / rejected
            def verdict(key):  # a method without a verdict: n/a, not '-' (nothing failed)
                return [_fmt(M[n][key]) if key in M[n] else NO_VERDICT for n in names]

            rows += [("poses accepted", "count", verdict("accepted")),
                     ("poses rejected", "count", verdict("rejected"))]
    elif mode == "localization":
        def pct(key):
            return lambda m: None if m.get(key) is None else 100 * m[key]

        rows = [
            ("scans", "count", col(lambda m: m["scans"])),
            ("placed (pose published)", "%", col(pct("placed_share"), 1)),
            ("placed within tolerance", "%", col(pct("correct_share"), 1)),
            ("wrong poses published", "count", col(lambda m: m["wrong_published"])),
            ("no pose (rejected, searching)", "count", col(lambda m: m["rejected"])),
            ("time to first pose (compute)", "ms", col(lambda m: m["time_to_first_pose_ms"], 1)),
            ("scans to first pose", "count", col(lambda m: m["first_pose_scans"])),
            ("lost / recoveries", "count", [f"{_fmt(M[n]['lost'])} / {_fmt(M[n]['recoveries'])}" for n in names]),
            ("rotation error p95 (placed)", "deg", col(lambda m: m["rot_err_deg"]["p95"], 4)),
            ("translation error p95 (placed)", "m", col(lambda m: m["trans_err_m"]["p95"], 4)),
            ("latency global p50 / p95", "ms/scan",
             [f"{_fmt(_get(M[n], 'latency_global_ms', 'p50'), 1)} / {_fmt(_get(M[n], 'latency_global_ms', 'p95'), 1)}"
              for n in names]),
            ("latency tracking p50 / p95", "ms/scan",
             [f"{_fmt(_get(M[n], 'latency_tracking_ms', 'p50'), 1)} / "
              f"{_fmt(_get(M[n], 'latency_tracking_ms', 'p95'), 1)}" for n in names]),
            ("map set-up", "ms", col(lambda m: m["setup_ms"], 0)),
        ]
    else:
        rows = [
            ("frames", "count", col(lambda m: m["frames"])),
            ("KITTI translation drift", "%", col(lambda m: m["kitti_t_err_pct"])),
            ("KITTI rotation drift", "deg/100 m", col(lambda m: m["kitti_r_err_deg_per_100m"])),
            ("ATE RMSE, SE(3)-aligned", "m", col(lambda m: m["ate_rmse_m"])),
            ("APE rotation RMSE, unaligned", "deg", col(lambda m: _get(m, "ape_rot_deg", "rmse"), 4)),
            ("RPE transl. mean, 1 frame", "m/frame", col(lambda m: m["rpe_trans_m"]["mean"], 4)),
            ("RPE rotation mean, 1 frame", "deg/frame", col(lambda m: m["rpe_rot_deg"]["mean"], 4)),
            ("runtime mean", "ms/frame", col(lambda m: m["runtime_ms"]["mean"], 1)),
            ("throughput", "frames/s", col(lambda m: m["fps"], 1)),
        ]
    return names, rows


#: the rows of the localization table that need ground truth
LOCALIZATION_TRUTH_ROWS = ("placed within tolerance", "wrong poses published", "rotation error p95 (placed)",
                           "translation error p95 (placed)")


def table_notes(mode: str, method_metrics: dict[str, dict], has_ground_truth: bool = True) -> list[str]:
    """Footnotes for the ``-`` cells of the comparison table: why a number could not be computed."""
    _names, rows = table_rows(mode, _clean(method_metrics))
    notes = []
    if any(NO_VERDICT in vals for _m, _u, vals in rows):
        notes.append(f"{NO_VERDICT}: the method gives no verdict on its poses (DeepBBS++ accepts or rejects each)")
    if mode == "localization":  # cells "a / b" hold two figures
        def empty(metric_rows):
            return any(c == "-" for _m, _u, vals in metric_rows for v in vals for c in v.split(" / "))

        truth_rows = [r for r in rows if r[0] in LOCALIZATION_TRUTH_ROWS]
        if empty(truth_rows) and not has_ground_truth:
            notes.append("-: needs ground truth (none in this recording): placed share, times and latency only")
        if empty([r for r in rows if r not in truth_rows]) or (empty(truth_rows) and has_ground_truth):
            notes.append("-: nothing to measure (no published pose, or no scan searched / tracked)")
        return notes
    if not any("-" in vals for _m, _u, vals in rows):
        return notes
    if mode == "odometry":
        if not has_ground_truth:
            notes.append("-: needs ground truth (none in this recording): only trajectories and runtime are "
                         "measured, no drift, ATE or RPE")
        else:
            lengths = [m.get("path_length_m") for m in _clean(method_metrics).values()]
            length = next((v for v in lengths if v is not None), None)
            if any(m.get("kitti_segments") == 0 for m in method_metrics.values()):
                shortest = min(metrics.KITTI_LENGTHS)
                have = f" (this drive: {length:.1f} m)" if length is not None else ""
                notes.append(f"-: KITTI drift is averaged over path segments of {shortest:g} m and longer; it needs "
                             f">= {shortest:g} m of path{have}")
            if any(m.get("frames", 0) < 2 for m in method_metrics.values()):
                notes.append("-: fewer than 2 frames: no motion to score")
    else:
        notes.append("-: nothing to summarise (no pair, or every registration of the method failed)")
    return notes


def table_definitions(mode: str, method_metrics: dict[str, dict]) -> list[str]:
    """What some rows count or how they are computed: the verdict counts with several trials per pair, the
    alignment behind the ATE (the plots' position error is unaligned)."""
    M = _clean(method_metrics)
    out = []
    if mode == "pairs":
        if any(m.get("registrations", m["pairs"]) != m["pairs"] for m in M.values()):
            verdict = ", poses accepted / rejected" if any("accepted" in m for m in M.values()) else ""
            out.append(f"success rate, runtime{verdict}: per registration (pairs x trials)")
    elif mode == "localization":
        out.append("within tolerance: published within eval.success_rot_deg / success_trans of the ground truth; "
                   "wrong: published outside them; time to first pose: compute time until the first published pose")
    elif any(m.get("ate_rmse_m") is not None for m in M.values()):
        out.append("ATE: after one SE(3) alignment (Umeyama, no scale) of the whole trajectory onto the ground "
                   "truth; APE rotation and the plots' position errors are unaligned (every trajectory starts at "
                   "the first ground-truth pose)")
    return out


def print_table(mode: str, method_metrics: dict[str, dict], title: str = "", console: Any = None,
                has_ground_truth: bool = True) -> None:
    from rich.console import Console
    from rich.table import Table

    names, rows = table_rows(mode, _clean(method_metrics))
    notes = table_notes(mode, method_metrics, has_ground_truth) + table_definitions(mode, method_metrics)
    table = Table(title=title or f"deepbbs-replay ({mode})", caption="\n".join(notes) or None,
                  caption_justify="left")
    table.add_column("metric")
    table.add_column("unit")
    for n in names:
        table.add_column(n, justify="right")
    for metric, unit, vals in rows:
        table.add_row(metric, unit, *vals)
    (console or Console()).print(table)
