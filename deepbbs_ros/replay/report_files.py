"""Replay outputs as files: the per-pair / per-frame / per-scan CSV and the TUM / KITTI trajectories in ``traj/``."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.replay.methods import topic_name
from deepbbs_ros.replay.runner import LocalizationResults, OdometryResults, PairResults


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

