"""Validation of a training run: fixed held-out pairs, the full DeepBBS++ registration on them, their error
summaries, the score that picks the best checkpoint, and a validation's one-line summary."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.train.cache import Drive
from deepbbs_ros.train.loss import deepbbs_loss, loss_options
from deepbbs_ros.train.pairs import Pair, collate, validation_pairs


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """arccos((trace(R_gt^T R) - 1) / 2) in degrees (CONVENTIONS.md)."""
    c = (np.trace(R_gt.T @ R_est) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def pair_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(rot_err_deg, trans_err_m) of one estimate against the ground truth."""
    return rotation_error_deg(T_est[:3, :3], T_gt[:3, :3]), float(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]))


def summarize_errors(rot: list[float], trans: list[float], rot_thr: float, trans_thr: float) -> dict[str, float]:
    """Mean / median / p95 / max of both errors and the success rate (both within thresholds)."""
    r, t = np.asarray(rot, dtype=np.float64), np.asarray(trans, dtype=np.float64)
    if len(r) == 0:
        return {"n": 0}
    ok = (r <= rot_thr) & (t <= trans_thr)
    return {
        "n": int(len(r)),
        "rot_mean_deg": float(r.mean()), "rot_median_deg": float(np.median(r)),
        "rot_p95_deg": float(np.percentile(r, 95)), "rot_max_deg": float(r.max()),
        "trans_mean_m": float(t.mean()), "trans_median_m": float(np.median(t)),
        "trans_p95_m": float(np.percentile(t, 95)), "trans_max_m": float(t.max()),
        "success": float(ok.mean()),
    }


@dataclass
class ValidationSet:
    """Fixed held-out pairs: as they come (``plain``) and with an extra random yaw (``yaw``)."""

    plain: list[Pair]
    yaw: list[Pair]
    yaw_deg: float

    @classmethod
    def build(cls, drives: list[Drive], config: Config, num_points: int, *, max_pairs: int = 32,
              stride: int = 10) -> ValidationSet:
        tc = config.train
        per_drive = max(1, math.ceil(max_pairs / max(1, len(drives))))
        folder = {d.name: str(d.meta.get("cache", "")) for d in drives}
        plain = validation_pairs(drives, num_points, stride=stride, max_dist=tc.max_dist, seed=tc.seed,
                                 per_drive=per_drive)
        yaw = validation_pairs(drives, num_points, stride=stride, max_dist=tc.max_dist, yaw_deg=tc.yaw_aug_deg,
                               seed=tc.seed + 1, per_drive=per_drive)
        return cls(_shared_out(plain, folder)[:max_pairs], _shared_out(yaw, folder)[:max_pairs], tc.yaw_aug_deg)


def _shared_out(pairs: list[Pair], folder: dict[str, str]) -> list[Pair]:
    """``pairs`` taken in turn from each validation folder (a pair's folder: its drive's cache), each folder's in its
    own order, so that cutting the list to ``max_pairs`` keeps every folder; one folder: the list as it is."""
    by_folder: dict[str, list[Pair]] = {}
    for p in pairs:
        by_folder.setdefault(folder.get(p.ref.split(":")[0], ""), []).append(p)
    queues = list(by_folder.values())
    out: list[Pair] = []
    for k in range(max((len(q) for q in queues), default=0)):
        out.extend(q[k] for q in queues if k < len(q))
    return out


def validation_record(model: Any, config: Config, vs: ValidationSet, val_drives: list[Drive], device: Any,
                      step: int, epoch: int) -> dict[str, Any]:
    """Errors of the full DeepBBS++ registration (deep iterations + refinement) on the fixed held-out pairs ``vs``,
    with and without the extra yaw, plus the one-pass network loss; ``model`` is left in training mode."""
    import torch

    from deepbbs_ros.core.registration import DeepBBSRegistration

    cfg, tc = config, config.train
    t0 = time.perf_counter()
    model.eval()
    reg = DeepBBSRegistration(cfg, model=model, device=str(device))
    rec: dict[str, Any] = {"kind": "val", "step": step, "epoch": epoch}
    with torch.no_grad():
        # one network pass on the plain pairs: the validation loss, every pair in it (hard ones too)
        opts = {**loss_options(cfg, epoch), "hard_pair_deg": 0.0}
        losses = []
        for k in range(0, len(vs.plain), tc.batch_size):
            src, tgt, R_gt, t_gt = (x.to(device) for x in collate(vs.plain[k : k + tc.batch_size]))
            out = model(src, tgt)
            terms = deepbbs_loss(out, src, tgt, R_gt, t_gt, **opts)
            losses.append(float(terms.total) * len(src))
        rec["val_loss"] = sum(losses) / max(1, len(vs.plain))
        folder = {d.name: str(d.meta.get("cache", "")) for d in val_drives}
        groups: dict[str, dict[str, Any]] = {}
        for name, pairs in (("plain", vs.plain), ("yaw", vs.yaw)):
            rot, trans, group = [], [], []
            for p in pairs:
                res = reg.register(p.source, p.target, preprocessed=True)
                r, t = pair_errors(res.T_target_source, p.T_target_source)
                rot.append(r)
                trans.append(t)
                group.append(folder.get(p.ref.split(":")[0], ""))
            rec[name] = summarize_errors(rot, trans, cfg.eval.success_rot_deg, cfg.eval.success_trans)
            for g in sorted(set(group)):  # each validation folder apart (e.g. a sensor mix and HDL-64E roads)
                k = [i for i, x in enumerate(group) if x == g]
                groups.setdefault(g, {})[name] = summarize_errors(
                    [rot[i] for i in k], [trans[i] for i in k], cfg.eval.success_rot_deg, cfg.eval.success_trans)
        if len(groups) > 1:
            rec["groups"] = groups
    model.train()
    rec["seconds"] = round(time.perf_counter() - t0, 2)
    return rec


def score(rec: dict[str, Any]) -> list[float]:
    """Higher is better: total success rate, then lower mean rotation and translation errors. With
    several validation folders each weighs the same (a mix of sensors cannot outvote HDL-64E roads)."""
    parts = list(rec["groups"].values()) if rec.get("groups") else [rec]
    n = len(parts)
    return [sum(g[s]["success"] for g in parts for s in ("plain", "yaw")) / n,
            -sum(g[s]["rot_mean_deg"] for g in parts for s in ("plain", "yaw")) / n,
            -sum(g[s]["trans_mean_m"] for g in parts for s in ("plain", "yaw")) / n]


def format_val(val: dict[str, Any]) -> str:
    p, y = val["plain"], val["yaw"]
    return (f"val step {val['step']} (epoch {val['epoch']}): loss {val['val_loss']:.4g} | "
            f"plain rot {p['rot_mean_deg']:.3f} deg trans {p['trans_mean_m']:.3f} m success {100 * p['success']:.1f}% "
            f"| +yaw rot {y['rot_mean_deg']:.3f} deg trans {y['trans_mean_m']:.3f} m success "
            f"{100 * y['success']:.1f}% ({val['seconds']:.0f} s)"
            + "".join(f" | {g} success {100 * v['plain']['success']:.1f}% / +yaw {100 * v['yaw']['success']:.1f}%"
                      for g, v in val.get("groups", {}).items()))
