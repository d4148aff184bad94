"""The localization benchmark's output (scripts/benchmarks/localization.py): the console table and localization.png."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)
from _localization_methods import LABELS, METHODS  # noqa: E402


def report(figs: dict, methods: list[str]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title="Global localization from no guess (placed: valid and within 1 deg / 0.3 m)")
    for col in ("map", "method", "queries", "placed", "wrong", "no pose", "ambiguous", "timeouts", "p50 s",
                "p95 s", "CPU p50 s", "CPU p95 s", "build s"):
        table.add_column(col, justify="right")

    def pct(v):
        return "-" if v is None else f"{100 * v:.0f} %"

    for mapname, fig in figs.items():
        for name in methods:
            s = fig["methods"].get(name, {})
            if "note" in s:
                table.add_row(mapname, name, s["note"][:40], *[""] * 10)
                continue
            for label, x in ((name, s), (f"{name} (repetitive)", s.get("repetitive"))):
                if not x or not x.get("queries"):
                    continue
                table.add_row(mapname, label, str(x["queries"]), pct(x.get("placed_share")), str(x.get("wrong_count")),
                              pct(x.get("none_share")), pct(x.get("ambiguous_share")), str(x.get("timeout_count")),
                              f"{x.get('time_s_p50', float('nan')):.2f}", f"{x.get('time_s_p95', float('nan')):.2f}",
                              f"{x.get('cpu_s_p50', float('nan')):.2f}", f"{x.get('cpu_s_p95', float('nan')):.2f}",
                              f"{s.get('build_s', float('nan')):.1f}" if x is s else "")
    Console(width=150).print(table)


def plot(fig: dict, out: Path) -> Path:
    """``out``/localization.png: per map and method the shares placed, wrong and with no pose (left) and the time
    to a first pose p50 / p95 (right), from ``fig`` (the figures of localization.json)."""
    plt = _common.pyplot()
    maps = list(fig["maps"])
    methods = [m for m in METHODS if any(m in fig["maps"][k]["methods"] for k in maps)]
    f, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    width = 0.8 / max(len(methods), 1)
    colors = {"placed": "tab:green", "wrong": "tab:red", "none": "0.75"}
    for j, name in enumerate(methods):
        x = np.arange(len(maps)) + (j - (len(methods) - 1) / 2) * width
        s = [fig["maps"][k]["methods"].get(name) or {} for k in maps]
        placed, wrong, none = (np.array([100 * (c.get(key) or 0.0) for c in s])
                               for key in ("placed_share", "wrong_share", "none_share"))
        for bottom, h, key in ((0, placed, "placed"), (placed, wrong, "wrong"), (placed + wrong, none, "none")):
            a.bar(x, h, width * 0.95, bottom=bottom, color=colors[key], edgecolor="k", lw=0.3,
                  label={"placed": "placed", "wrong": "wrong pose", "none": "no pose"}[key] if j == 0 else None)
        for xi in x:
            a.text(xi, 101, str(j + 1), ha="center", va="bottom", fontsize=7)
        p50 = [c.get("time_s_p50") or np.nan for c in s]
        p95 = [c.get("time_s_p95") or np.nan for c in s]
        b.bar(x, p95, width * 0.95, color=f"C{j}", alpha=0.35)
        b.bar(x, p50, width * 0.95, color=f"C{j}", label=f"{j + 1}: {LABELS.get(name, name)}")
    for ax in (a, b):
        ax.set_xticks(np.arange(len(maps)), maps)
    a.set_ylabel("% of the queries")
    a.set_ylim(0, 110)
    a.set_title("placed (1 deg / 0.3 m), wrong, no pose (bars: methods 1, 2, 3)")
    a.legend(fontsize=7, loc="lower left")
    b.axhline(1.0, color="k", lw=0.8, ls=":")
    b.axhline(3.0, color="k", lw=0.8, ls="--")
    b.set_ylabel("s per query from no guess")
    b.set_title("time to a first pose: p50 (dark), p95 (light); goal lines 1 s, 3 s")
    b.legend(fontsize=7, loc="upper left")
    return _common.save(f, out, "localization.png")
