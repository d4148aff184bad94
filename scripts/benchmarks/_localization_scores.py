"""The localization benchmark's scores (scripts/benchmarks/localization.py): an answer judged against the truth, the
shares and times of a set of answers, the map verdict's reliability, every map pooled."""

from __future__ import annotations

import numpy as np
from _localization_data import Query
from _localization_methods import Answer

ROT_OK_DEG, TRANS_OK_M = 1.0, 0.3


def judge(ans: Answer, q: Query) -> dict:
    """One row: errors against the truth and the verdict class (placed / wrong / none)."""
    from deepbbs_ros.metrics import pair_errors

    row = {"place": q.place, "kind": q.kind, "s": q.s, "repetitive": q.repetitive, "valid": ans.valid,
           "reason": ans.reason, "time_s": ans.time_s, "exact_time_s": ans.exact_time_s, "timeout": ans.timeout,
           "cpu_s": ans.cpu_s, "exact_cpu_s": ans.exact_cpu_s,
           "rot_err_deg": None,
           "trans_err_m": None, "probability": ans.probability}
    close = False
    if ans.T_map_scan is not None and np.all(np.isfinite(ans.T_map_scan)):
        r, t = pair_errors(ans.T_map_scan[None], q.T_map_scan[None])
        row["rot_err_deg"], row["trans_err_m"] = float(r[0]), float(t[0])
        close = bool(r[0] <= ROT_OK_DEG and t[0] <= TRANS_OK_M)
    row["close"] = close  # the pose is right, published or not
    row["outcome"] = ("placed" if close else "wrong") if ans.valid else "none"
    return row


def summarize(rows: list[dict]) -> dict:
    """Shares over ``rows`` (one method, one set of queries): placed, wrong accepted, no pose, ambiguous,
    timeouts, right but rejected; time per query p50 / p95 (all queries) and of the placed ones."""
    n = len(rows)
    if n == 0:
        return {"queries": 0}
    out = {"queries": n}
    for k in ("placed", "wrong", "none"):
        out[f"{k}_share"] = sum(r["outcome"] == k for r in rows) / n
    out["wrong_count"] = sum(r["outcome"] == "wrong" for r in rows)
    out["ambiguous_share"] = sum(r["outcome"] == "none" and r["reason"].startswith("ambiguous") for r in rows) / n
    out["timeout_count"] = sum(bool(r["timeout"]) for r in rows)
    out["right_but_rejected_share"] = sum(r["outcome"] == "none" and r["close"] for r in rows) / n
    t = np.array([r["time_s"] for r in rows if r["time_s"] is not None and np.isfinite(r["time_s"])])
    if len(t):
        out["time_s_p50"], out["time_s_p95"], out["time_s_max"] = (float(np.percentile(t, 50)),
                                                                   float(np.percentile(t, 95)), float(t.max()))
    te = np.array([r.get("exact_time_s", np.nan) for r in rows], dtype=np.float64)
    te = te[np.isfinite(te)]
    if len(te):  # MapLocalizer's exact twin (GICP on one thread)
        out["exact_time_s_p50"], out["exact_time_s_p95"] = float(np.percentile(te, 50)), float(np.percentile(te, 95))
    for k in ("cpu_s", "exact_cpu_s"):  # CPU time per query (this process and its network process)
        c = np.array([r.get(k, np.nan) for r in rows], dtype=np.float64)
        c = c[np.isfinite(c)]
        if len(c):
            out[f"{k}_p50"], out[f"{k}_p95"] = float(np.percentile(c, 50)), float(np.percentile(c, 95))
    tp = np.array([r["time_s"] for r in rows if r["outcome"] == "placed"])
    if len(tp):
        out["placed_time_s_p50"], out["placed_time_s_p95"] = float(np.percentile(tp, 50)), float(np.percentile(tp, 95))
    placed = [r for r in rows if r["outcome"] == "placed"]
    if placed:
        out["placed_rot_err_deg_mean"] = float(np.mean([r["rot_err_deg"] for r in placed]))
        out["placed_trans_err_m_mean"] = float(np.mean([r["trans_err_m"] for r in placed]))
    return out


def reliability(rows: list[dict], edges=(0.0, 0.05, 0.2, 0.5, 0.7, 0.9, 1.0)) -> dict:
    """The map verdict's reliability over ``rows``: per bin of the answer's probability, [answers, share right
    (within 1 deg / 0.3 m of the truth, published or not)]."""
    out = {}
    p = np.array([r.get("probability", np.nan) for r in rows], np.float64)
    right = np.array([r["close"] for r in rows], bool)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (p >= lo) & ((p < hi) | (hi >= 1.0) & (p <= 1.0))
        if m.any():
            out[f"{lo:g}-{hi:g}"] = [int(m.sum()), float(right[m].mean())]
    return out


def aggregate(figs: dict, methods: list[str]) -> dict:
    """Every map's rows pooled per method (simulated maps only, and everything)."""
    out = {}
    for name in methods:
        for label, maps in (("sim", [k for k in figs if k != "real"]), ("all", list(figs))):
            rows = [r for k in maps for r in figs[k]["rows"].get(name, [])]
            if rows:
                out.setdefault(name, {})[label] = summarize(rows)
            boot = [r for k in maps for r in figs[k].get("boot_rows", {}).get(name, [])]
            if boot:
                out[name][f"{label}_boot"] = summarize(boot)
    return out
