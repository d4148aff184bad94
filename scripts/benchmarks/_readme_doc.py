"""render_docs.py's README "Results" table."""

from __future__ import annotations

import re
from pathlib import Path

from _localization_doc import loc_time
from _render_format import NOT_RUN, ms, num, pct, ratio, table
from _runtime_doc import scans


def readme(docs: dict[str, dict | None], d: Path) -> list[str]:
    header = ["what", "protocol", "DeepBBS++", "baseline", "details"]
    reg = ((docs.get("registration") or {}).get("figures") or {}).get("protocols") or {}
    odo = ((docs.get("odometry") or {}).get("figures") or {}).get("runs") or {}
    fl = (docs.get("fleet") or {}).get("figures")
    link_pairs = "[pairs](docs/benchmarks.md#registration-of-raw-pairs)"
    link_live = "[live node](docs/benchmarks.md#live-node-latency)"

    def reg_cell(proto, group, m, what):
        if not docs.get("registration"):
            return NOT_RUN
        c = ((reg.get(proto) or {}).get(group) or {}).get(m)
        if c is None:
            return NOT_RUN
        if what == "success":
            return pct(c["success_pct"], c["cases"])
        return f"{num(c.get('rot_deg_mean'), 3)} deg / {num(c.get('trans_m_mean'), 3)} m"

    odo_run = next((r for n, r in odo.items() if re.fullmatch(r"sim urban \d+f clean", n)), None)

    def odo_cell(m):
        if not docs.get("odometry") or odo_run is None:
            return NOT_RUN
        v = odo_run["methods"].get(m)
        if v is None:
            return "-"
        drift = "-" if v.get("kitti_t_err_pct") is None else f"{v['kitti_t_err_pct']:.2f} %"
        return f"{drift} / {num(v.get('ate_rmse_m'), 3)} m"

    def node(name, method, first_only):
        doc = docs.get(name)
        if doc is None:
            return NOT_RUN
        rs = [r for r in doc["figures"]["runs"] if r["method"] == method and not r["busy"]]
        if first_only:
            rs = [r for r in rs if r["layout"] == "velodyne"][:1]
        if not rs:
            return NOT_RUN
        if len(rs) == 1:
            r = rs[0]
            return f"{100 * r['answered']:.1f} %, {ms(r['p50_ms'])} / {ms(r['p99_ms'])} ms"

        def span(key):
            vals = [r[key] for r in rs if r[key] is not None]
            return "-" if not vals else f"{ms(min(vals))}-{ms(max(vals))}"
        low = min(100 * r["answered"] for r in rs)
        return (f"{low:.1f} %{'' if low == 100 else ' or more'}, {span('p50_ms')} / {span('p99_ms')} ms "
                f"({len(rs)} runs)")

    def any_time(m):
        c = ((reg.get("any-start") or {}).get("all") or {}).get(m)
        if not docs.get("registration") or c is None:
            return NOT_RUN
        r = c.get("p50_over_kiss_matcher_gicp")
        return f"p50 {ms(c['p50_ms'])} ms" + ("" if m != "deepbbs++" or r is None else
                                               f" ({ratio(r)} KISS-Matcher + GICP's on its cases)")

    def paper_cell():
        c = ((reg.get("as-they-come") or {}).get("kitti") or {}).get("deepbbs++paper")
        if not docs.get("registration") or c is None:
            return NOT_RUN
        return f"{pct(c['success_pct'], c['cases'])}, {reg_cell('as-they-come', 'kitti', 'deepbbs++paper', 'error')}"

    def verdict_cell():
        v = ((docs.get("registration") or {}).get("figures") or {}).get("verdict") or {}
        a, dp = v.get("deepbbs++"), v.get("different_places")
        if not docs.get("registration") or a is None:
            return NOT_RUN
        acc = pct(a.get("correct_accepted_pct"), a.get("correct"))
        rej = NOT_RUN if dp is None else pct(dp.get("rejected_pct"), dp.get("pairs"))
        return f"{acc} / {rej}"

    gs_fig = (docs.get("good_start") or {}).get("figures") or {}

    def good_start_cell(m):
        tim, wrong = gs_fig.get("timing"), (gs_fig.get("wrong_start") or {}).get("all") or {}
        if not tim:
            return NOT_RUN
        worst = [max(((t.get(m) or {}).get(k) or 0) for t in tim.values())
                 for k in ("p50_vs_gicp", "p99_vs_gicp", "cpu_mean_vs_gicp")]
        w = wrong.get(m)
        return " / ".join(ratio(v) for v in worst) + ("" if not w else f"; {w['accepted_wrong']} wrong")

    loc_pooled = ((docs.get("localization") or {}).get("figures") or {}).get("pooled") or {}

    def loc_cell(m):
        c = (loc_pooled.get(m) or {}).get("all")
        if not docs.get("localization") or not c:
            return NOT_RUN
        return f"{pct(100 * c['placed_share'], c['queries'])}, {c['wrong_count']} wrong, {loc_time(c)} ms"

    def kidnap_far():
        kd = (docs.get("kidnap") or {}).get("figures") or {}
        dist = [x for c in kd.values() for x in c.get("kidnap_distance_m") or []]
        return f"{num(min(dist), 0)} m along" if dist else "elsewhere in"

    def kidnap_cell():
        kd = (docs.get("kidnap") or {}).get("figures")
        if not kd:
            return NOT_RUN
        lost = [x for c in kd.values() for x in c.get("lost_after_scans") or [None]]
        back = [x for c in kd.values() for x in c.get("relocalized_after_scans") or [None]]
        rel = [c["relocalize_p50_s"] for c in kd.values() if c.get("relocalize_p50_s") is not None]
        return (f"lost after {scans(lost)} scans, {sum(c['wrong_poses'] for c in kd.values())} wrong, found again "
                f"after {scans(back)} scan{'s' if max((x or 0) for x in back) > 1 else ''} back"
                + (f" (relocalization p50 {ms(1e3 * max(rel))} ms)" if rel else ""))

    if fl is None:
        fleet_cell = NOT_RUN
    else:
        top = max(r["workers"] for r in fl["rows"])
        cells = [f"`{r['label']}` {ratio(r['speedup'])}" for r in fl["rows"] if r["workers"] == top]
        fleet_cell = ", ".join(cells) + f" with {top} worker{'s' if top > 1 else ''}"
    rows = [
        ["raw scan pairs from any start: success", "real KITTI pairs up to 5 m apart, source moved by any yaw and up "
         "to 10 m, no initial guess; within 1 deg / 0.3 m", reg_cell("any-start", "kitti", "deepbbs++", "success"),
         "GICP: " + reg_cell("any-start", "kitti", "gicp", "success"), link_pairs],
        ["raw scan pairs from any start: time", "every any-start case, real and simulated; p50 of the whole call, "
         "both scans' preprocessing included (KISS-Matcher: over the cases it ran)", any_time("deepbbs++"),
         "KISS-Matcher + GICP: " + any_time("kiss-matcher+gicp"), link_pairs],
        ["precision, pairs as they come", "all pairs (real and held-out simulated); mean rotation / translation "
         "error of the successes", reg_cell("as-they-come", "all", "deepbbs++", "error"),
         "GICP: " + reg_cell("as-they-come", "all", "gicp", "error"), link_pairs],
        ["the learned part alone", "the paper's DeepBBS++ (deep passes and spatial-BBS refinement, no GICP), real "
         "KITTI pairs as they come; success and mean errors", paper_cell(),
         "GICP: " + reg_cell("as-they-come", "kitti", "gicp", "success"), link_pairs],
        ["the verdict", "correct results accepted / pairs of two different places rejected", verdict_cell(), "-",
         "[verdict](docs/benchmarks.md#the-verdict)"],
        ["registration from a good start", "raw pairs given a start, real and simulated: p50 / p99 / CPU per pair "
         "x GICP's (worst data set); wrong poses accepted from starts slid 2-10 m", good_start_cell("good_start"),
         "`register(T_init)`: " + good_start_cell("register"),
         "[good start](docs/benchmarks.md#registration-from-a-good-start)"],
        ["global localization in a prior map", "no initial guess, 1 km simulated maps and real scans; placed within 1 "
         "deg / 0.3 m, wrong poses, p50 / p95 to the first pose", loc_cell("maplocalizer"),
         "KISS-Matcher + GICP: " + loc_cell("kiss-matcher+gicp"),
         "[localization](docs/benchmarks.md#global-localization-in-a-prior-map)"],
        ["losing the pose and finding it again", f"tracking a simulated drive, the sensor carried {kidnap_far()} the "
         "map or into another world for two scans; scans to declare it lost, wrong poses, scans back until found",
         kidnap_cell(), "-", "[kidnap](docs/benchmarks.md#losing-the-pose-and-finding-it-again)"],
        ["odometry", "held-out simulated urban drive, raw sweeps; KITTI drift % / ATE m", odo_cell("deepbbs++"),
         "KISS-ICP: " + odo_cell("kiss-icp"), "[odometry](docs/benchmarks.md#odometry)"],
        ["live node, 10 Hz clouds from another process", "odometry mode, HDL-64E layout; share answered, p50 / p99 "
         "latency", node("node_latency_odometry", "deepbbs", True),
         "GICP node: " + node("node_latency_odometry", "gicp", True), link_live],
        ["live node, pair mode", "KITTI scans, every source a new scan; share answered, p50 / p99 latency",
         node("node_latency_pair", "deepbbs", False), "GICP node: " + node("node_latency_pair", "gicp", False),
         link_live],
        ["live node, localization mode", "tracking in a prior map of a simulated drive; share answered, p50 / p99",
         node("node_latency_localization", "deepbbs", False),
         "GICP node, latched map: " + node("node_latency_localization", "gicp", False), link_live],
        ["fleet replay on Ray", "simulated recordings, 1 and 2 workers; speedup", fleet_cell, "-",
         "[fleet](docs/benchmarks.md#a-fleet-of-recordings-on-ray)"],
    ]
    return table(header, rows)
