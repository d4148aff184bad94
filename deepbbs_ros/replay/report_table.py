"""The replay's terminal table: rows per mode with units, footnotes for the ``-`` cells, definitions, rich output."""

from __future__ import annotations

import math
from typing import Any

from deepbbs_ros import metrics
from deepbbs_ros.replay.report_metrics import _clean


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
