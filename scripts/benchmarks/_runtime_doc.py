"""render_docs.py's sections of the live node and the machine: node latency, kidnap, first contact, a busy computer,
decode, simulator, fleet, threads."""

from __future__ import annotations

from pathlib import Path

from _render_format import NOT_RUN, Notes, command, ms, not_run_table, num, ratio, table

# the pair-mode goal docs/benchmarks.md states (node_latency.py's --goal-* defaults)
GOAL_ANSWERED_PCT, GOAL_P99_MS, GOAL_RATIO = 99.0, 150.0, 1.5
# the goal docs/benchmarks.md states for the node in a prior map
GOAL_NODE_LOC_RATIO = 1.2


def node_rows(recs: list[dict]) -> dict:
    """(layout, stream, run, busy) -> {method: record}, in the file's order."""
    rows: dict = {}
    for r in recs:
        rows.setdefault((r["layout"], r["stream"], r["run"], r["busy"]), {})[r["method"]] = r
    return rows


def node_cell(r: dict | None, notes: Notes) -> str:
    if r is None:
        return NOT_RUN
    s = f"{100 * r['answered']:.1f} % ({r['pairs']}), {ms(r['p50_ms'])} / {ms(r['p99_ms'])}"
    return s + (notes.mark(r["error"]) if r.get("error") else "")


def node_ratio(rs: dict) -> str:
    a, b = rs.get("deepbbs"), rs.get("gicp")
    if not a or not b or a["p50_ms"] is None or not b["p50_ms"]:
        return "-"
    return ratio(a["p50_ms"] / b["p50_ms"])


def goal(r: dict | None) -> str:
    if r is None or r["p50_ms"] is None or r["p99_ms"] is None:
        return "-"
    missed = [w for ok, w in ((100 * r["answered"] >= GOAL_ANSWERED_PCT, f"answered < {GOAL_ANSWERED_PCT:g} %"),
                              (r["p99_ms"] <= GOAL_P99_MS, f"p99 > {GOAL_P99_MS:g} ms"),
                              (r["p99_ms"] <= GOAL_RATIO * r["p50_ms"], f"p99 > {GOAL_RATIO:g} x p50")) if not ok]
    return "met" if not missed else "missed: " + ", ".join(missed)


LAYOUTS = {"velodyne": "HDL-64E layout", "ouster": "OS1-128 layout"}


def node_latency_odometry(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["odometry mode", "DeepBBS++ node: answered (scans), p50 / p99 ms", "GICP anchor node",
              "p50 / anchor's"]
    if doc is None:
        return out + not_run_table(header, list(LAYOUTS.values()))
    notes = Notes()
    rows = []
    for (layout, _stream, run, busy), rs in node_rows(doc["figures"]["runs"]).items():
        label = LAYOUTS.get(layout, layout) + (f", run {run}" if run != "1" else "") + (", busy" if busy else "")
        rows.append([label, node_cell(rs.get("deepbbs"), notes), node_cell(rs.get("gicp"), notes), node_ratio(rs)])
    return out + table(header, rows) + notes.lines()


def node_latency_pair(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["pair mode, KITTI, Velodyne layout", "DeepBBS++ node: answered (pairs), p50 / p99 ms",
              "GICP anchor node", "p50 / anchor's", "goal"]
    if doc is None:
        return out + not_run_table(header, ["consecutive scans", "fixed target"])
    notes = Notes()
    rows = []
    kinds = {"consecutive": "consecutive scans", "fixed": "fixed target"}
    runs = doc["figures"]["runs"]
    with_cpu = any(r.get("cpu_ms") is not None for r in runs)
    with_paths = any(r.get("paths") for r in runs)
    if with_cpu:
        header.insert(4, "CPU ms per pair (x anchor's)")
    if with_paths:
        header.insert(-1, "DeepBBS++ paths: GICP from the good start / deep / search")
    for (layout, stream, run, busy), rs in node_rows(runs).items():
        label = f"{kinds.get(stream, stream)}, run {run}" + ("" if layout == "velodyne" else f", {layout}") + (
            ", busy" if busy else "")
        row = [label, node_cell(rs.get("deepbbs"), notes), node_cell(rs.get("gicp"), notes), node_ratio(rs)]
        if with_cpu:
            row.append(node_cpu(rs))
        if with_paths:
            row.append(node_paths(rs.get("deepbbs")))
        rows.append(row + [goal(rs.get("deepbbs"))])
    return out + table(header, rows) + notes.lines()


def node_cpu(rs: dict) -> str:
    """The DeepBBS++ node's CPU ms per period (every process of it) and its ratio to the anchor's."""
    a, b = (rs.get(m) or {} for m in ("deepbbs", "gicp"))
    if a.get("cpu_ms") is None:
        return "-"
    return f"{ms(a['cpu_ms'])}" + (f" ({ratio(a['cpu_ms'] / b['cpu_ms'])})" if b.get("cpu_ms") else "")


def node_paths(r: dict | None) -> str:
    p = (r or {}).get("paths") or {}
    return "-" if not p else " / ".join(str(p.get(k, 0)) for k in ("gicp", "deepbbs", "search"))


def node_latency_localization(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["localization mode", "DeepBBS++ node: answered (scans), p50 / p99 ms", "GICP anchor node (latched map)",
              "p50 / p99 / CPU per scan (x anchor's)", "DeepBBS++ paths: GICP first / deep / search", "goal"]
    if doc is None:
        return out + not_run_table(header, ["HDL-64E layout"])
    notes = Notes()
    rows = []
    for (layout, _stream, run, busy), rs in node_rows(doc["figures"]["runs"]).items():
        label = LAYOUTS.get(layout, layout) + f", run {run}" + (", busy" if busy else "")
        a, b = rs.get("deepbbs") or {}, rs.get("gicp") or {}
        rats = {k: "-" if a.get(k) is None or not b.get(k) else ratio(a[k] / b[k])
                for k in ("p50_ms", "p99_ms", "cpu_ms")}
        cpu = "-" if a.get("cpu_ms") is None else f"{ms(a['cpu_ms'])} ms"
        if not a or not b:
            verdict_ = "-"
        else:
            missed = [f"{what} > {GOAL_NODE_LOC_RATIO:g} x the anchor's" for what, k in
                      (("p50", "p50_ms"), ("p99", "p99_ms"), ("CPU", "cpu_ms"))
                      if a.get(k) is not None and b.get(k) and a[k] > GOAL_NODE_LOC_RATIO * b[k]]
            if 100 * (a.get("answered") or 0) < GOAL_ANSWERED_PCT:
                missed.append(f"answered < {GOAL_ANSWERED_PCT:g} %")
            verdict_ = "met" if not missed else "missed: " + ", ".join(missed)
        rows.append([label, node_cell(rs.get("deepbbs"), notes), node_cell(rs.get("gicp"), notes),
                     f"{rats['p50_ms']} / {rats['p99_ms']} / {rats['cpu_ms']} ({cpu})", node_paths(a), verdict_])
    return out + table(header, rows) + notes.lines()


KIDNAPS = {"other": "into another world (a highway drive)", "same": "elsewhere in the same map"}


def scans(v: list | None) -> str:
    """A count of scans per kidnap: its range over the kidnaps, "-" for a kidnap without one."""
    if not v:
        return "-"
    known = [x for x in v if x is not None]
    if not known:
        return "never"
    lo, hi = min(known), max(known)
    text = f"{lo}" if lo == hi else f"{lo}-{hi}"
    return text + (f" ({len(v) - len(known)} never)" if len(known) < len(v) else "")


def kidnap(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["the sensor carried", "kidnaps", "lost after (scans)", "wrong poses", "rejected scan p50 ms "
              "(x a tracked scan's)", "found again after (scans back)", "relocalization p50 ms"]
    if doc is None:
        return out + not_run_table(header, list(KIDNAPS.values()))
    rows, dist = [], []
    for kind, c in doc["figures"].items():
        rej, trk, rel = (c.get(k) for k in ("rejected_scan_p50_s", "tracked_scan_p50_s", "relocalize_p50_s"))
        rows.append([KIDNAPS.get(kind, kind), str(c["kidnaps"]), scans(c.get("lost_after_scans")),
                     str(c["wrong_poses"]), f"{ms(None if rej is None else 1e3 * rej)} "
                     f"({ratio(c.get('rejected_over_tracked'))})", scans(c.get("relocalized_after_scans")),
                     ms(None if rel is None else 1e3 * rel)])
        dist += c.get("kidnap_distance_m") or []
    trk = [c.get("tracked_scan_p50_s") for c in doc["figures"].values() if c.get("tracked_scan_p50_s")]
    tail = ([f"A tracked scan: p50 {ms(1e3 * min(trk))}-{ms(1e3 * max(trk))} ms in the same runs."] if trk else [])
    if dist:
        tail.append(f"Elsewhere in the same map: {num(min(dist), 0)}-{num(max(dist), 0)} m from the last tracked "
                    "pose, turned 115 deg.")
    return out + table(header, rows) + ([""] + tail if tail else [])


def first_contact(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    labels = ["scans answered", "ready in (model + warm-up)", "from the process start, imports included"]
    if doc is None:
        return out + not_run_table(["", "runs"], labels)
    runs = doc["figures"]["runs"]
    header = ["", *(f"run {i + 1}" for i in range(len(runs)))]
    rows = [["scans answered", *(f"{r['answered']} / {r['scans']}" for r in runs)],
            ["ready in (model + warm-up)", *(f"{num(r.get('ready_s'), 1)} s" for r in runs)],
            ["from the process start, imports included", *(f"{num(r.get('launch_s'), 1)} s" for r in runs)]]
    return out + table(header, rows)


POLICIES = {"passive": "PASSIVE (default)", "default": "unset (libgomp's default)"}


def busy(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["`OMP_WAIT_POLICY`", "idle: DeepBBS++ p50 / p95 ms (x GICP's p50)",
              "busy: DeepBBS++ p50 / p95 ms (x GICP's p50)"]
    if doc is None:
        return out + not_run_table(header, list(POLICIES.values()))
    cells = {(c["policy"], c["load"]): c for c in doc["figures"]["cells"]}
    rows = []
    for pol in dict.fromkeys([*(p for p, _ in cells), *POLICIES]):
        row = [POLICIES.get(pol, pol)]
        for load in ("idle", "busy"):
            c = cells.get((pol, load))
            row.append(NOT_RUN if c is None else
                       f"{ms(c['deepbbs_p50_ms'])} / {ms(c['deepbbs_p95_ms'])} ({ratio(c['p50_over_gicp'])}; "
                       f"{c['pairs']} pairs)")
        rows.append(row)
    return out + table(header, rows)


def decode(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["case", "median ms", "CPU median ms"]
    if doc is None:
        return out + not_run_table(header, ["xyz", "xyz + intensity, t, ring", "encode"])
    fig = doc["figures"]
    rows = [[case, num(c["median_ms"], 2), num(c.get("cpu_median_ms"), 2)] for case, c in fig["cases"].items()]
    return out + table(header, rows) + ["", f"{fig.get('points')} points ({fig.get('valid_points')} valid), "
                                            f"{fig.get('runs')} runs per case, goal {num(fig.get('goal_ms'), 1)} ms."]


def simulator(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    if doc is None:
        return out + not_run_table(["", "urban", "suburban", "highway", "open_road", "overall", "a 100-frame drive"],
                                   ["frames/s"])
    fig = doc["figures"]
    scenes = fig["scenes"]
    header = ["", *scenes, "overall", "a 100-frame drive"]
    rows = [["frames/s", *(num(s["fps"], 1) for s in scenes.values()), num(fig["overall_fps"], 1),
             f"{num(fig['seconds_per_100_frames'], 1)} s"]]
    return out + table(header, rows) + ["", f"{fig.get('frames')} frames per scene, {fig.get('lidar')}."]


def fleet(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    if doc is None:
        return out + not_run_table(["methods", "1 worker: fleet s (command s)", "2 workers", "speedup",
                                    "frames/s per CPU (2 workers)"], ["GICP + KISS-ICP", "DeepBBS++"])
    fig = doc["figures"]
    rows_ = fig["rows"]
    workers = sorted({r["workers"] for r in rows_})
    top = workers[-1]
    at = f"{top} worker{'s' if top > 1 else ''}"
    header = ["methods", *(f"{w} worker{'s' if w > 1 else ''}: fleet s (command s)" for w in workers),
              f"speedup ({at})", f"frames/s per CPU ({at})"]
    notes = Notes()
    rows = []
    for label in dict.fromkeys(r["label"] for r in rows_):
        by = {r["workers"]: r for r in rows_ if r["label"] == label}
        cells = []
        for w in workers:
            r = by.get(w)
            if r is None:
                cells.append("-")
                continue
            bad = "" if r.get("ok") == r.get("total") else notes.mark(f"{r.get('ok')} of {r.get('total')} "
                                                                         "recordings finished")
            cells.append(f"{num(r['fleet_wall_s'], 1)} ({num(r['cmd_wall_s'], 1)})" + bad)
        t = by.get(top) or {}
        rows.append([f"`{label}`", *cells, ratio(t.get("speedup")), num(t.get("fps_per_cpu"), 2)])
    return (out + table(header, rows) + notes.lines()
            + ["", f"{fig['recordings']} recordings x {fig['frames']} frames."])


def threads(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["method", "1 thread: ms / frame", "every core: ms / frame", "1 thread / every core"]
    if doc is None:
        return out + not_run_table(header, ["deepbbs++", "gicp", "kiss-icp"])
    fig = doc["figures"]
    rows = [[f"`{m}`", num(c["one_thread_ms"], 1), num(c["every_core_ms"], 1), ratio(c["ratio"])]
            for m, c in fig["methods"].items()]
    frames = {c["frames"] for c in fig["methods"].values()}
    return out + table(header, rows) + ["", f"Medians over {', '.join(map(str, sorted(frames)))} frames per setting "
                                            f"({fig['rounds']} passes over the recording, the settings alternating)."]
