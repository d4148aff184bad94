#!/usr/bin/env python3
"""The summary run_all.sh prints: the figures docs/benchmarks.md states, read back from the benchmarks' JSON files
in one results folder (``python scripts/benchmarks/_summary.py OUT``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def f(v, fmt=".3f", unit=""):
    return "-" if v is None else f"{v:{fmt}}{unit}"


def load(out: Path, name: str) -> dict | None:
    path = out / name
    return json.loads(path.read_text())["figures"] if path.is_file() else None


def registration(fig: dict) -> None:
    print("\n## registration (success %, mean rot deg / trans m of the successes, p50 ms, p50 / GICP's p50)")
    for proto, groups in fig["protocols"].items():
        for g in ("real", "sim"):
            for m, c in (groups.get(g) or {}).items():
                print(f"  {proto:<13} {g:<4} {m:<18} {f(c['success_pct'], '.1f')} % ({c['cases']}), "
                      f"{f(c['rot_deg_mean'])} deg / {f(c['trans_m_mean'])} m, p50 {f(c['p50_ms'], '.0f')} ms, "
                      f"p95 {f(c['p95_ms'], '.0f')} ms, x{f(c['p50_over_gicp'], '.2f')} GICP's"
                      + (f", x{f(c['p50_over_kiss_matcher_gicp'], '.2f')} KISS-Matcher + GICP's"
                         if c.get("p50_over_kiss_matcher_gicp") else ""))
    v = fig["verdict"]
    for m in ("deepbbs++", "deepbbs++local"):
        if m in v:
            print(f"  verdict, {m}: correct accepted {f(v[m]['correct_accepted_pct'], '.1f')} % ({v[m]['correct']}), "
                  f"wrong poses rejected {f(v[m]['wrong_rejected_pct'], '.1f')} % ({v[m]['wrong']})")
    if "different_places" in v:
        d = v["different_places"]
        print(f"  verdict, different places rejected {f(d['rejected_pct'], '.1f')} % ({d['pairs']}), "
              f"highest score {f(d['highest_score'])}, p50 {f(d['p50_ms'], '.0f')} ms")


def odometry(fig: dict) -> None:
    print("\n## odometry (drift %, ATE m, frames/s, frames/s / KISS-ICP's)")
    for run, r in fig["runs"].items():
        for m, v in r["methods"].items():
            print(f"  {run:<28} {m:<10} {f(v['kitti_t_err_pct'])} %, {f(v['ate_rmse_m'])} m, "
                  f"{f(v['fps'], '.1f')} frames/s, x{f(v['fps_over_kiss_icp'], '.2f')}")


def node_latency(out: Path, name: str) -> None:
    path = out / name / "runs.jsonl"
    if not path.is_file():
        return
    recs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    print(f"\n## {name} (per run: answered %, p50 / p99 ms; the GICP anchor node in the same run)")
    for r in recs:
        print(f"  {r['layout']:<8} {r['stream']:<11} {r['run']:<8} {'busy ' if r['busy'] else ''}{r['method']:<7} "
              f"{100 * r['answered']:.0f} %, {f(r['p50_ms'], '.1f')} / {f(r['p99_ms'], '.1f')} ms"
              + (f", CPU {f(r['cpu_ms'], '.1f')} ms per period" if r.get("cpu_ms") is not None else "")
              + (f", paths {paths(r)}" if paths(r) else "")
              + (f" ({r['error']})" if r.get("error") else ""))


def paths(r: dict) -> str:
    """pair and localization modes: which registration path answered (gicp / deepbbs / search), from /diagnostics."""
    p = {k.removeprefix("paths."): v for k, v in (r.get("diagnostics") or {}).items() if k.startswith("paths.")}
    return "" if not any(v not in ("0", 0) for v in p.values()) else ", ".join(f"{k} {v}" for k, v in p.items())


def good_start(fig: dict) -> None:
    print("\n## good start (raw pairs given a start: p50 / p99 ms, CPU mean ms, x GICP's; goal <= 1.1x)")
    for name, ms_ in (fig.get("timing") or {}).items():
        for m, c in ms_.items():
            print(f"  {name:<14} {m:<10} {f(c['p50_ms'], '.0f')} / {f(c['p99_ms'], '.0f')} ms, CPU "
                  f"{f(c['cpu_mean_ms'], '.0f')} ms (x{f(c.get('p50_vs_gicp'), '.2f')} / "
                  f"x{f(c.get('p99_vs_gicp'), '.2f')}"
                  f" / x{f(c.get('cpu_mean_vs_gicp'), '.2f')}), paths {c.get('paths')}")
    wrong = fig.get("wrong_start") or {}
    for name, ms_ in wrong.items():
        if name == "calibration":
            continue
        g, r, gs = (ms_.get(m) or {} for m in ("gicp", "register", "good_start"))
        print(f"  wrong starts {name:<10} GICP alone {g.get('wrong')} wrong of {g.get('cases')}; register(T_init) "
              f"{r.get('accepted_wrong')} wrong accepted, good_start {gs.get('accepted_wrong')} (GICP first: "
              f"{(gs.get('paths') or {}).get('gicp', 0)})")
    if wrong.get("calibration"):
        print(f"  calibration {wrong['calibration']}")


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    out = Path(argv[0])
    fig = load(out, "decode.json")
    if fig:
        print("\n## decode (median ms; goal <= 5 ms)")
        for case, c in fig["cases"].items():
            print(f"  {case}: {f(c['median_ms'])} ms (CPU {f(c['cpu_median_ms'])} ms)")
    fig = load(out, "simulator.json")
    if fig:
        print(f"\n## simulator: {f(fig['overall_fps'], '.1f')} frames/s, a 100-frame drive in "
              f"{f(fig['seconds_per_100_frames'], '.1f')} s; per scene: "
              + ", ".join(f"{k} {f(v['fps'], '.1f')}" for k, v in fig["scenes"].items()))
    fig = load(out, "registration.json")
    if fig:
        registration(fig)
    fig = load(out, "good_start.json")
    if fig:
        good_start(fig)
    fig = load(out, "deskew.json")
    if fig:
        print("\n## deskew (all scenes: success %, mean rot deg / trans m on the pairs every variant solves)")
        for name, v in fig["variants"].items():
            a = v["all"]
            print(f"  {name:<14} {f(a['success_pct'], '.1f')} %, {f(a['rot_deg_mean'], '.4f')} / "
                  f"{f(a['trans_m_mean'], '.4f')} m")
    fig = load(out, "odometry.json")
    if fig:
        odometry(fig)
    fig = load(out, "kidnap.json")
    if fig:
        print("\n## kidnap (lost after scans, wrong poses, rejected scan p50 s (x tracked), relocalized p50 s)")
        for kind, c in fig.items():
            print(f"  {kind:<6} lost after {c['lost_after_scans']}, wrong {c['wrong_poses']}, rejected "
                  f"{f(c['rejected_scan_p50_s'])} s (x{f(c.get('rejected_over_tracked'), '.2f')}), relocalized "
                  f"{f(c['relocalize_p50_s'])} s after {c.get('relocalized_after_scans')} scans back")
    fig = load(out, "busy.json")
    if fig:
        print("\n## busy computer (p50 / p95 ms per raw pair, DeepBBS++ and GICP)")
        for c in fig["cells"]:
            print(f"  {c['policy']:<8} {c['load']:<5} DeepBBS++ {c['deepbbs_p50_ms']:.0f} / {c['deepbbs_p95_ms']:.0f}, "
                  f"GICP {c['gicp_p50_ms']:.0f} / {c['gicp_p95_ms']:.0f}, x{c['p50_over_gicp']:.2f}")
    fig = load(out, "first_contact.json")
    if fig:
        print("\n## first contact (answered, ready in s, from the process start s)")
        for r in fig["runs"]:
            print(f"  {r['answered']}/{r['scans']}, {f(r['ready_s'], '.1f')} s, {f(r['launch_s'], '.1f')} s")
    node_latency(out, "node_latency_odometry")
    node_latency(out, "node_latency_pair")
    node_latency(out, "node_latency_localization")
    fig = load(out, "fleet.json")
    if fig:
        print(f"\n## fleet ({fig['recordings']} recordings x {fig['frames']} frames)")
        for r in fig["rows"]:
            print(f"  {r['label']:<18} {r['workers']} worker(s): fleet {r['fleet_wall_s']:.1f} s (command "
                  f"{r['cmd_wall_s']:.1f} s), x{r['speedup']:.2f}, {r['fps_per_cpu']:.2f} frames/s/CPU")
    fig = load(out, "threads.json")
    if fig:
        print("\n## fixed evaluation threads (median ms per frame: 1 thread / every core)")
        for m, c in fig["methods"].items():
            print(f"  {m:<10} {c['one_thread_ms']:.1f} / {c['every_core_ms']:.1f} ms, x{c['ratio']:.2f}")
    fig = load(out, "localization.json")
    if fig:
        print("\n## localization from no guess (placed / wrong / no pose of the queries, p50 / p95 s per query)")
        for mapname, m in fig["maps"].items():
            for name, c in m["methods"].items():
                if "note" in c:
                    print(f"  {mapname:<10} {name:<18} {c['note']}")
                    continue
                print(f"  {mapname:<10} {name:<18} {f(c.get('placed_share'), '.0%')} / {c.get('wrong_count')} / "
                      f"{f(c.get('none_share'), '.0%')} of {c['queries']}, {f(c.get('time_s_p50'), '.2f')} / "
                      f"{f(c.get('time_s_p95'), '.2f')} s, {c.get('timeout_count', 0)} timeouts")
                for kind, k in ((c.get("by_kind") or {}) if name == "maplocalizer" else {}).items():
                    print(f"  {'':<10}   {kind:<16} {f(k.get('placed_share'), '.0%')} / {k.get('wrong_count')} / "
                          f"{f(k.get('none_share'), '.0%')} of {k['queries']}")
                rep = c.get("repetitive") if name == "maplocalizer" else None
                if rep:
                    print(f"  {'':<10}   {'repetitive':<16} {f(rep.get('placed_share'), '.0%')} / "
                          f"{rep.get('wrong_count')} / {f(rep.get('none_share'), '.0%')} of {rep['queries']}")
        for name, p in fig.get("pooled", {}).items():
            a = p.get("all") or {}
            print(f"  pooled     {name:<18} {f(a.get('placed_share'), '.0%')} / {a.get('wrong_count')} / "
                  f"{f(a.get('none_share'), '.0%')} of {a.get('queries')}, {f(a.get('time_s_p50'), '.2f')} / "
                  f"{f(a.get('time_s_p95'), '.2f')} s"
                  + (" (goal: >= 99 % placed, 0 wrong, p50 <= 1 s, p95 <= 3 s)" if name == "maplocalizer" else ""))
    print("\nplots: " + ", ".join(sorted(p.name for p in out.glob("*.png"))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
