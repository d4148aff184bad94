"""What a finished replay says about itself, beyond its figures (no ROS import, no output files).

* :func:`nothing_answered`: not one pair, frame or scan got an answer (every registration failed, no scan placed):
  the run is not complete, whatever its length; the line says why.
* :func:`frame_offset`: every localization pose is off the truth by one constant rigid offset: the map and the
  ground truth are in different frames (a map re-anchored after it was made, truth in another world frame).
"""

from __future__ import annotations

import re
from collections import Counter
from typing import Any

import numpy as np

from deepbbs_ros import metrics

MIN_OFFSET_POSES = 3  # placed poses with truth needed to judge a constant offset


def nothing_answered(mode: str, res: Any) -> str | None:
    """One line when the run (``res``: PairResults, OdometryResults or LocalizationResults of ``mode``) has
    something to answer and not one answer: no pair with an estimate from any method, no odometry frame registered
    by any method, no scan placed in the map. None otherwise (and for an empty run)."""
    if mode == "pairs":
        if not res.records:
            return None
        if any(not r.error and np.isfinite(r.T_est).all() for r in res.records):
            return None
        return (f"not one of the {res.pairs} pairs got an estimate from any method ("
                f"{_common(r.error or 'non-finite estimate' for r in res.records)})")
    if mode == "odometry":
        n = res.frames
        if n < 2 or getattr(res, "registered", 1):
            return None
        fails = [f.split(": ", 1)[-1] for v in res.failed.values() for f in v]
        return (f"not one of the {n - 1} registrations of the {n} frames gave an estimate, with any method "
                f"({_common(fails or ['no estimate'])})")
    if not res.records or any(r.valid for r in res.records):
        return None
    return (f"not one of the {len(res.records)} scans was placed in the map "
            f"({_common(r.reason or r.event for r in res.records)})")


def _common(reasons: Any) -> str:
    """``k of n: <the most common reason>`` of an iterable of reasons; reasons that differ only in their numbers
    (a point count, a frame number) count as one, shown by its first instance."""
    reasons = [str(r) for r in reasons]
    kinds = [re.sub(r"\d+(\.\d+)?", "#", r) for r in reasons]
    kind, k = Counter(kinds).most_common(1)[0]
    return f"{k} of {len(reasons)}: {reasons[kinds.index(kind)]}"


def frame_offset(records: list, rot_tol_deg: float, trans_tol_m: float) -> dict | None:
    """A constant rigid offset between the placed poses and the truth, when there is one.

    records: LocalizationRecord-like (``valid``, ``T_map_est`` and ``T_map_gt`` (4, 4) or None). Of the placed
    poses with truth, each gives ``C_k = T_gt_k inv(T_est_k)``, the correction that would put the estimate on the
    truth; C is their mean (rotations: the SO(3) projection of the summed rotation matrices; translations: the mean
    of ``t_gt - R_C t_est``). An offset is reported when at least ``MIN_OFFSET_POSES`` poses take part, their raw
    errors are not within tolerance (median above ``rot_tol_deg`` or ``trans_tol_m``) and after ``C`` they are
    (median within both): every pose is wrong by the same rigid motion, which is the map's frame against the
    truth's, not the localization's error.

    Returns None, or a dict: ``translation_m`` [x, y, z] and ``yaw_deg`` of ``C`` (= ``T_truth_map``, the map
    frame's pose in the truth's frame), ``raw_trans_err_m`` / ``corrected_trans_err_m`` / ``corrected_rot_err_deg``
    (medians), ``poses`` and ``message`` (one line)."""
    pairs = [(r.T_map_est, r.T_map_gt) for r in records
             if r.valid and r.T_map_gt is not None and np.isfinite(r.T_map_est).all()]
    if len(pairs) < MIN_OFFSET_POSES:
        return None
    est = np.stack([p[0] for p in pairs])
    gt = np.stack([p[1] for p in pairs])
    raw = np.array([metrics.pair_errors(e, g) for e, g in zip(est, gt)])  # (K, 2) rot deg, trans m
    if np.median(raw[:, 0]) <= rot_tol_deg and np.median(raw[:, 1]) <= trans_tol_m:
        return None  # the poses are right as they are
    R_sum = np.einsum("kij,klj->il", gt[:, :3, :3], est[:, :3, :3])  # sum of R_gt R_est^T
    U, _, Vt = np.linalg.svd(R_sum)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    C = np.eye(4)
    C[:3, :3] = R
    C[:3, 3] = (gt[:, :3, 3] - est[:, :3, 3] @ R.T).mean(axis=0)
    fixed = np.array([metrics.pair_errors(C @ e, g) for e, g in zip(est, gt)])
    if np.median(fixed[:, 0]) > rot_tol_deg or np.median(fixed[:, 1]) > trans_tol_m:
        return None  # not one offset: the poses are wrong each its own way
    yaw = float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))
    t = C[:3, 3]
    out = {"translation_m": [float(v) for v in t], "yaw_deg": yaw, "poses": len(pairs),
           "raw_trans_err_m": float(np.median(raw[:, 1])), "corrected_trans_err_m": float(np.median(fixed[:, 1])),
           "corrected_rot_err_deg": float(np.median(fixed[:, 0]))}
    out["message"] = (f"the map and the ground truth are in different frames: every one of the {len(pairs)} placed "
                      f"poses is off the truth by one rigid offset (the map frame in the truth's: translation "
                      f"[{t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}] m, yaw {yaw:.1f} deg; median error "
                      f"{out['raw_trans_err_m']:.2f} m, {out['corrected_trans_err_m']:.2f} m after it): the "
                      "localization is likely right and its errors measure the frames, not the poses")
    return out
