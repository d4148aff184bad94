"""The model card's figures from the evaluation's pairs (:mod:`deepbbs_ros.train.evaluate`): the summary per
variant, method and scene (mean / RMSE / median / p95 / max errors, success, time), the goal checks, and the tables
(rich for the console, Markdown for the card)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from deepbbs_ros.config import Config

GOALS = {"rot_mean_deg": 0.05, "trans_mean_m": 0.04, "success": 0.99, "success_yaw": 0.95}


def _summary(rot: list[float], trans: list[float], ms: list[float], cfg: Config) -> dict[str, Any]:
    from deepbbs_ros.metrics import success_rate, summarize

    r, t = np.asarray(rot, dtype=np.float64), np.asarray(trans, dtype=np.float64)
    sr, st = summarize(r), summarize(t)
    return {
        "pairs": int(len(r)),
        "rot_mean_deg": sr["mean"], "rot_rmse_deg": sr["rmse"], "rot_median_deg": sr["median"],
        "rot_p95_deg": sr["p95"], "rot_max_deg": sr["max"],
        "trans_mean_m": st["mean"], "trans_rmse_m": st["rmse"], "trans_median_m": st["median"],
        "trans_p95_m": st["p95"], "trans_max_m": st["max"],
        "success": success_rate(r, t, cfg.eval.success_rot_deg, cfg.eval.success_trans) if len(r) else float("nan"),
        "ms_mean": float(np.mean(ms)) if ms else float("nan"),
    }


def summarise(records: list[dict[str, Any]], variants: Sequence[str], methods: Sequence[str], scenes: Sequence[str],
              cfg_used: Config) -> dict[str, Any]:
    """``summary[variant][method][scene | "all"]`` of the pairs' ``records`` (``report["pairs"]``)."""
    summary: dict[str, Any] = {}
    for variant in variants:
        summary[variant] = {}
        for m in methods:
            summary[variant][m] = {}
            for sc in [*scenes, "all"]:
                sel = [r for r in records if r["variant"] == variant and r["method"] == m
                       and (sc == "all" or r["scene"] == sc)]
                summary[variant][m][sc] = _summary([r["rot_err_deg"] for r in sel], [r["trans_err_m"] for r in sel],
                                                   [r["ms"] for r in sel], cfg_used)
    return summary


def goal_checks(summary: dict[str, Any]) -> dict[str, Any]:
    """The ``deepbbs++`` figures over all scenes against :data:`GOALS` (none without that method)."""
    goals = {}
    if "deepbbs++" in summary["plain"]:
        a = summary["plain"]["deepbbs++"]["all"]
        goals = {
            "rot_mean_deg": {"goal": GOALS["rot_mean_deg"], "measured": a["rot_mean_deg"],
                             "met": a["rot_mean_deg"] <= GOALS["rot_mean_deg"]},
            "trans_mean_m": {"goal": GOALS["trans_mean_m"], "measured": a["trans_mean_m"],
                             "met": a["trans_mean_m"] <= GOALS["trans_mean_m"]},
            "success": {"goal": GOALS["success"], "measured": a["success"], "met": a["success"] >= GOALS["success"]},
        }
        if "yaw" in summary:
            y = summary["yaw"]["deepbbs++"]["all"]
            goals["success_yaw"] = {"goal": GOALS["success_yaw"], "measured": y["success"],
                                    "met": y["success"] >= GOALS["success_yaw"]}
    return goals


def print_report(report: dict[str, Any], console: Any = None) -> None:
    """Rich tables: per variant, method and scene type, with units in the header."""
    from rich.console import Console
    from rich.table import Table

    if console is None:
        console = Console()
        if not console.is_terminal:  # log files: wide enough for every column
            console = Console(width=132)
    for variant, per_method in report["summary"].items():
        yaw = report["protocol"]["yaw_deg"]
        title = "held-out pairs, no initial guess"
        if variant == "yaw":
            title += f", extra random yaw up to {yaw:g} deg"
        table = Table(title=title)
        for col, just in (("method", "left"), ("scene", "left"), ("pairs", "right"), ("MAE rot [deg]", "right"),
                          ("MTE [m]", "right"), ("p95 rot [deg]", "right"), ("p95 trans [m]", "right"),
                          ("success [%]", "right"), ("time [ms]", "right")):
            table.add_column(col, justify=just)
        for method, per_scene in per_method.items():
            for scene, s in per_scene.items():
                if not s["pairs"]:
                    continue
                table.add_row(method, scene, str(s["pairs"]), f"{s['rot_mean_deg']:.4f}", f"{s['trans_mean_m']:.4f}",
                              f"{s['rot_p95_deg']:.3f}", f"{s['trans_p95_m']:.3f}", f"{100 * s['success']:.1f}",
                              f"{s['ms_mean']:.0f}", end_section=scene == "all")
        console.print(table)
    for name, g in report.get("goals", {}).items():
        console.print(f"goal {name}: measured {g['measured']:.4g} vs goal {g['goal']:g}: "
                      f"{'met' if g['met'] else 'MISSED'}")


def markdown_report(report: dict[str, Any]) -> str:
    """The summary tables as Markdown (per variant: method x scene)."""
    lines = []
    yaw = report["protocol"]["yaw_deg"]
    for variant, per_method in report["summary"].items():
        extra = f", extra random yaw up to {yaw:g} deg" if variant == "yaw" else ""
        lines += [f"**Held-out pairs, no initial guess{extra}**", "",
                  "| method | scene | pairs | MAE rot (deg) | MTE (m) | p95 rot (deg) | p95 trans (m) | success (%) "
                  "| time (ms) |", "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
        for method, per_scene in per_method.items():
            for scene, s in per_scene.items():
                if s["pairs"]:
                    lines.append(f"| {method} | {scene} | {s['pairs']} | {s['rot_mean_deg']:.4f} | "
                                 f"{s['trans_mean_m']:.4f} | {s['rot_p95_deg']:.3f} | {s['trans_p95_m']:.3f} | "
                                 f"{100 * s['success']:.1f} | {s['ms_mean']:.0f} |")
        lines.append("")
    for name, g in report.get("goals", {}).items():
        lines.append(f"- goal `{name}`: measured {g['measured']:.4g}, goal {g['goal']:g}: "
                     f"{'met' if g['met'] else '**missed**'}")
    return "\n".join(lines) + "\n"
