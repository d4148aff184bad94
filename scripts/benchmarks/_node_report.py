"""node_latency.py's figures: one run's result (:class:`RunResult`), its printed report, runs.jsonl, latency.png and
the judgement against the goal."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ANCHOR = "gicp"  # the GICP anchor node, run beside the DeepBBS++ node on the same clouds
#: the node's stages, as /diagnostics reports them (latency_ms.<stage>)
STAGES = ("input_wait", "decode", "preprocess", "queue_wait", "register", "register.preprocess",
          "register.good_start", "register.network_wait", "register.polish", "register.global", "register.crop",
          "register.register", "map_crop", "publish", "total")  # fmt: skip


@dataclass
class RunResult:
    pairs: int = 0
    latencies_ms: list[float] = field(default_factory=list)
    periods: list[int] = field(default_factory=list)  # the measured period of each answer (0 = the first measured)
    frames: list[tuple[int, int]] = field(default_factory=list)  # its (source, target) frames (odometry: (k, k))
    diagnostics: dict[str, str] = field(default_factory=dict)
    error: str = ""
    cpu: str = ""  # CPU ms per period per thread group (cpu_line)
    cpu_ms: float = float("nan")  # CPU ms per period, every process of the node together (cpu_total)
    first_pose_s: float = float("nan")  # localization: first scan published -> first pose received (s)
    after_first: tuple[int, int] = (0, 0)  # localization: scans published after the first pose: (answered, all)
    ready_s: float = float("nan")  # node process started -> its input subscribed (plain node: map built; managed:
    #: the configure and activate transitions requested as soon as its services answer)
    configure_s: float = float("nan")  # managed node: the configure transition (the map and the model loaded)
    activate_s: float = float("nan")  # managed node: the activate transition (subscribed)
    published: dict[int, float] = field(default_factory=dict)  # localization: every stamp -> s after the first scan
    poses: dict[int, float] = field(default_factory=dict)  # localization: answered stamp -> s after the first scan
    xyz: dict[int, tuple[float, float, float]] = field(default_factory=dict)  # answered stamp -> the pose's position

    @property
    def answered(self) -> float:
        return len(self.latencies_ms) / self.pairs if self.pairs else 0.0

    def pct(self, q: float) -> float:
        return float(np.percentile(self.latencies_ms, q)) if self.latencies_ms else float("nan")


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if b > 0 and np.isfinite(a) and np.isfinite(b) else "-"


def stage_line(d: dict[str, str]) -> str:
    """The node's median / p99 per stage and its drop counters, from its last /diagnostics message."""
    stages = [k for k in STAGES if f"latency_ms.{k}" in d]
    parts = [f"{k} {d[f'latency_ms.{k}'].replace('median ', '').replace(' p99 ', ' / ').split(' max')[0]}"
             for k in stages]  # fmt: skip
    drops = (f"pairs dropped {d.get('pairs dropped (newest wins)', '?')}, clouds dropped before preprocessing "
             f"{d.get('clouds dropped before preprocessing (oldest first)', '?')}, preprocessing cache hits / "
             f"misses {d.get('preprocessing cache hits / misses', '?')}, poses the verdict rejected "
             f"{d.get('poses not published (the verdict rejected them)', '?')}")  # fmt: skip
    paths = [f"{k.removeprefix('paths.')} {v}" for k, v in d.items() if k.startswith("paths.")]
    if paths:  # pair mode: which registration path answered (GICP from the good start, the deep passes, the search)
        drops += f"; paths: {', '.join(paths)}"
    return f"median / p99 ms: {', '.join(parts) or 'no diagnostics'}; {drops}"


def save_runs(out: Path, layout: str, stream: str, runs: list[tuple[str, bool, dict[str, RunResult]]]) -> list[dict]:
    """Append each (run, node) of one configuration to ``out``/runs.jsonl; -> the records."""
    recs = []
    for label, busy, results in runs:
        for method, r in results.items():
            recs.append({
                "layout": layout, "stream": stream, "run": label, "busy": busy, "method": method,
                "pairs": r.pairs, "answered": r.answered, "p50_ms": r.pct(50), "p99_ms": r.pct(99),
                "error": r.error, "cpu": r.cpu,
                "cpu_ms": round(r.cpu_ms, 2) if np.isfinite(r.cpu_ms) else None, "diagnostics": r.diagnostics,
                "first_pose_s": r.first_pose_s if np.isfinite(r.first_pose_s) else None,
                "answered_after_first_pose": list(r.after_first),
                "samples": [{"period": k, "source": f[0], "target": f[1], "latency_ms": round(v, 2)}
                            for k, v, f in zip(r.periods, r.latencies_ms, r.frames)],
            })  # fmt: skip
    with (out / "runs.jsonl").open("a") as f:
        for rec in recs:
            f.write(json.dumps(rec, default=float) + "\n")
    return recs


def plot_runs(args, recs: list[dict]) -> Path | str:
    """``args.out``/latency.png: per configuration (layout, stream), each run's latency per measured period
    (left) and its sorted latencies (right: the share of pairs answered within a time), the goal's p99 line
    drawn in; -> the path, or why there is none."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "none (matplotlib is not installed)"
    configs = sorted({(r["layout"], r["stream"]) for r in recs})
    fig, axes = plt.subplots(len(configs), 2, figsize=(13, 3.2 * len(configs)), squeeze=False)
    for row, (layout, stream) in zip(axes, configs):
        for r in (r for r in recs if (r["layout"], r["stream"]) == (layout, stream) and r["samples"]):
            k = [s["period"] for s in r["samples"]]
            v = np.array([s["latency_ms"] for s in r["samples"]])
            name = f"{r['method']} {r['run']}"
            style = "--" if r["method"] == ANCHOR else "-"
            row[0].plot(k, v, style, lw=0.8, label=name)
            share = np.arange(1, len(v) + 1) / max(r["pairs"], 1)  # of the pairs published: drops stay below 1
            row[1].plot(np.sort(v), share, style, lw=1.0, label=f"{name} ({100 * r['answered']:.0f} %)")
        for ax in row:
            ax.grid(alpha=0.3)
        row[0].axhline(args.goal_p99, color="k", lw=0.8, ls=":")
        row[1].axvline(args.goal_p99, color="k", lw=0.8, ls=":")
        row[0].set(title=f"{layout}, {stream}: latency per period", xlabel="measured period", ylabel="ms")
        row[1].set(title=f"{layout}, {stream}: share of pairs answered within", xlabel="ms", ylabel="share",
                   ylim=(0, 1.02))
        row[1].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    path = args.out / "latency.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


@dataclass
class Judged:
    label: str
    busy: bool
    result: RunResult

    def failures(self, args) -> list[str]:
        r = self.result
        if r.error:
            return ["node failed"]
        p50, p99, ans = r.pct(50), r.pct(99), 100 * r.answered
        need_ans, need_p99 = (args.busy_answered, args.busy_p99) if self.busy else (args.goal_answered, args.goal_p99)
        out = []
        if ans < need_ans:
            out.append(f"answered {ans:.0f} % < {need_ans:g} %")
        if not p99 <= need_p99:
            out.append(f"p99 {p99:.0f} ms > {need_p99:g} ms")
        if not self.busy and not p99 <= args.goal_ratio * p50:
            out.append(f"p99 / p50 {p99 / p50:.2f} > {args.goal_ratio:g}")
        return out


def report(title: str, args, runs: list[tuple[str, bool, dict[str, RunResult]]]) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console(width=160)
    t = Table(title=f"{title}\n{args.mode} mode, {args.rate:g} Hz, {args.seconds:g} s measured per run (after "
                    f"{args.warmup:g} s warm-up); latency = source published -> PoseStamped received")  # fmt: skip
    for c in ("run", "method", "pairs", "answered", "p50 ms", "p99 ms", "p99 / p50", "p50 / anchor",
              "p99 / anchor", "CPU ms", "CPU / anchor"):  # fmt: skip
        t.add_column(c, justify="left" if c in ("run", "method") else "right")
    for label, _, results in runs:
        anchor = results.get(ANCHOR)
        ok = anchor and not anchor.error
        a50, a99, acpu = (anchor.pct(50), anchor.pct(99), anchor.cpu_ms) if ok else (np.nan, np.nan, np.nan)
        for method, r in results.items():
            if r.error:
                t.add_row(label, method, "-", "failed", "-", "-", "-", "-", "-", "-", "-")
                continue
            t.add_row(label, method + (" (anchor)" if method == ANCHOR else ""), str(r.pairs),
                      f"{100 * r.answered:.0f} %", f"{r.pct(50):.1f}", f"{r.pct(99):.1f}",
                      _ratio(r.pct(99), r.pct(50)), _ratio(r.pct(50), a50), _ratio(r.pct(99), a99),
                      f"{r.cpu_ms:.1f}", _ratio(r.cpu_ms, acpu))  # fmt: skip
    con.print(t)
    for label, _, results in runs:
        for method, r in results.items():
            if r.error:
                con.print(f"[red]{label} {method}: node failed[/red]: {r.error[-2000:]}")
            else:
                con.print(f"  {label} {method}: {stage_line(r.diagnostics)}", soft_wrap=True)
                if args.mode == "localization" and method != ANCHOR:
                    n, m, d = *r.after_first, r.diagnostics
                    con.print(f"  {label} {method}: boot: first pose {r.first_pose_s:.2f} s after the first scan; "
                              f"scans published after it answered: {n} of {m} ({100 * n / max(m, 1):.1f} %); "
                              f"followed after the search {d.get('localization.scans followed after a search', '-')}, "
                              f"dropped unanswered {d.get('localization.scans dropped unanswered', '-')}",
                              soft_wrap=True)
                if r.cpu:
                    con.print(f"  {label} {method}: {r.cpu}", soft_wrap=True)
