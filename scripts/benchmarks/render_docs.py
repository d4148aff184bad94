#!/usr/bin/env python3
"""Fill the figure tables of docs/benchmarks.md, docs/sensors.md and the README's "Results" table from the benchmarks'
JSON files.

    python scripts/benchmarks/render_docs.py OUT --copy     # after run_all.sh --out OUT: copy, then render
    python scripts/benchmarks/render_docs.py docs/benchmarks --check   # the pages are a render of the JSON

Every table sits between ``<!-- bench:NAME -->`` and ``<!-- /bench -->`` markers; what is between them is
replaced by a render of RESULTS_DIR's ``NAME.json`` files (each ``{"command", "machine", "figures"}``), with
the command each one records. A benchmark with no JSON shows ``not run`` (never an older figure), a figure the
JSON lacks shows ``-`` with the reason where the JSON gives one, and a plot is shown only when its PNG is in
docs/benchmarks/.

--copy first empties docs/benchmarks/ and copies into it RESULTS_DIR's figure files (``*.json``) and the
plots the page shows; the live node latency runs (``node_latency_*/runs.jsonl``) become
``node_latency_*.json`` (every run's figures, without the per-pair samples and diagnostics), with the command
and start time run_all.sh records under ``logs/``. Then the pages are rendered from docs/benchmarks/, so what is
committed there is what the pages state.

--check renders without writing and exits 1 when a page differs from the render (a hand-edited or stale figure).

Formatting (fixed): success and answered shares in % with one decimal and the count in brackets; rotation
errors in degrees and translation errors in metres with three decimals (four in the deskew table, whose
errors are millimetres); times in ms without decimals (decode: two decimals); ratios as ``x`` with two
decimals; frames per second with one decimal; drift in % with two decimals; verdict scores with three decimals.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _families_doc  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "benchmarks.md"
SENSORS_PAGE = "sensors.md"  # docs/sensors.md: the per-family tables (bench:families), when the page exists
README = ROOT / "README.md"
DOCS_BENCH = ROOT / "docs" / "benchmarks"
NOT_RUN = "not run"
BLOCK = re.compile(r"(<!-- bench:([\w-]+) -->\n)(.*?)(<!-- /bench -->)", re.S)
# the pair-mode goal docs/benchmarks.md states (node_latency.py's --goal-* defaults)
GOAL_ANSWERED_PCT, GOAL_P99_MS, GOAL_RATIO = 99.0, 150.0, 1.5
# the plots each benchmark's section shows, as named in docs/benchmarks/
PLOTS = {
    "registration": [("registration.png", "Success per protocol and method, real and simulated pairs; p50 time "
                                          "with its ratio to GICP's")],
    "verdict": [("verdict.png", "result.score of correct results, wrong poses and different places; the threshold")],
    "deskew": [("deskew.png", "Mean translation error per variant")],
    "odometry": [("odometry.png", "ATE, drift and throughput per run and method")],
    "node_latency_odometry": [("node_latency_odometry.png", "Odometry mode: latency per period and share "
                                                            "answered within a time")],
    "node_latency_pair": [("node_latency_pair.png", "Pair mode on KITTI scans: latency per period and share "
                                                    "answered within a time")],
    "first_contact": [("first_contact.png", "Start-up time and scans answered per run")],
    "busy": [("busy.png", "p50 per raw pair, with the ratio to GICP's")],
    "decode": [("decode.png", "Median time per case against the goal")],
    "simulator": [("simulator.png", "Frames per second per scene type")],
    "fleet": [("fleet.png", "Fleet wall time and frames/s per CPU against workers")],
    "threads": [("threads.png", "Median time per frame with one thread and with every core")],
    "good_start": [("good_start.png", "p50, p99 and CPU against GICP's per data set; wrong poses per scene")],
    "localization": [("localization.png", "Placed, wrong and no pose per map and method; time to a first pose")],
    "node_latency_localization": [("node_latency_localization.png", "Localization mode: latency per period and "
                                                                    "share answered within a time")],
}
BENCHMARKS = ["registration", "good_start", "deskew", "odometry", "localization", "node_latency_odometry",
              "node_latency_pair", "node_latency_localization", "kidnap", "first_contact", "busy", "decode",
              "simulator", "fleet", "threads", "families"]
NODE_LATENCY = ("node_latency_odometry", "node_latency_pair", "node_latency_localization")
NODE_KEEP = ("layout", "stream", "run", "busy", "method", "pairs", "answered", "p50_ms", "p99_ms", "error", "cpu",
             "cpu_ms")
# the goals docs/benchmarks.md states: the good start (ratios to GICP's), localization, the node in a prior map
GOAL_GOOD_START = 1.1
GOAL_LOC_PLACED_PCT, GOAL_LOC_P50_S, GOAL_LOC_P95_S = 99.0, 1.0, 3.0
GOAL_NODE_LOC_RATIO = 1.2


# ---------------------------------------------------------------------------------------------------- formatting
def num(v, digits: int) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def pct(v, n=None) -> str:
    if v is None:
        return "-"
    return f"{v:.1f} %" + (f" ({n})" if n is not None else "")


def ratio(v) -> str:
    return "-" if v is None else f"x{v:.2f}"


def ms(v) -> str:
    return "-" if v is None else f"{v:.0f}"


class Notes:
    """Footnotes of one table: ``mark(reason)`` -> `` (a)``, the same mark for the same reason."""

    def __init__(self):
        self.reasons: list[str] = []

    def mark(self, reason: str) -> str:
        if reason not in self.reasons:
            self.reasons.append(reason)
        return f" ({chr(ord('a') + self.reasons.index(reason))})"

    def lines(self) -> list[str]:
        return ["", *(f"- ({chr(ord('a') + i)}) {r}" for i, r in enumerate(self.reasons))] if self.reasons else []


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def not_run_table(header: list[str], labels: list[str]) -> list[str]:
    return table(header, [[label] + [NOT_RUN] * (len(header) - 1) for label in labels])


def short_path(token: str) -> str:
    """A path in a recorded command: relative to the repository, or PATH/TO/<its last two parts> outside it (an
    absolute one, one in the home folder, or a relative one leading out of the repository: ``../data/kitti/00``)."""
    if token.startswith("../"):
        path = (ROOT / token).resolve()  # the benchmarks run from the repository's root
    elif token.startswith(("/", "~/")):
        path = Path(token).expanduser()
    else:
        return token
    if path == ROOT or ROOT in path.parents:
        return str(path.relative_to(ROOT))
    return "PATH/TO/" + "/".join(path.parts[-2:])


def command(doc: dict | None) -> list[str]:
    if doc is None:
        return []
    when = (doc.get("machine") or {}).get("date_utc") or "date not recorded"
    if not doc.get("command"):
        return [f"Command not recorded ({when}).", ""]
    cmd = " ".join(short_path(t) for t in doc["command"].split(" "))
    return [f"Measured by `python {cmd}` ({when}).", ""]


def plots(name: str, docs_bench: Path) -> list[str]:
    return [f"![{alt}](benchmarks/{png})\n" for png, alt in PLOTS.get(name, []) if (docs_bench / png).is_file()]


# ---------------------------------------------------------------------------------------------------- loading
def load_node_latency(folder: Path, name: str) -> dict | None:
    """``name``.json, else ``name``/runs.jsonl (a run_all.sh folder) made into the same shape."""
    if (folder / f"{name}.json").is_file():
        return json.loads((folder / f"{name}.json").read_text())
    runs = folder / name / "runs.jsonl"
    if not runs.is_file():
        return None
    recs = [json.loads(line) for line in runs.read_text().splitlines() if line.strip()]
    cmd_file = folder / "logs" / f"{name}.command"
    machine_file = folder / "logs" / f"{name}.machine.json"
    try:
        mach = json.loads(machine_file.read_text()) if machine_file.is_file() else None
    except json.JSONDecodeError:
        mach = None
    return {"command": cmd_file.read_text().strip() if cmd_file.is_file() else None, "machine": mach,
            "figures": {"runs": [node_keep(r) for r in recs]}}


def node_keep(r: dict) -> dict:
    """A runs.jsonl record without its samples and diagnostics; the registration paths that answered (pair and
    localization modes: ``paths.gicp``, ``paths.deepbbs``, ``paths.search`` of the diagnostics) as ``paths``."""
    out = {k: r.get(k) for k in NODE_KEEP if k in r or k != "cpu_ms"}
    paths = {k.removeprefix("paths."): int(v) for k, v in (r.get("diagnostics") or {}).items()
             if k.startswith("paths.") and str(v).isdigit()}
    if paths and any(paths.values()):
        out["paths"] = paths
    return out


def load_all(folder: Path) -> dict[str, dict | None]:
    docs = {}
    for name in BENCHMARKS:
        if name in NODE_LATENCY:
            docs[name] = load_node_latency(folder, name)
        else:
            path = folder / f"{name}.json"
            docs[name] = json.loads(path.read_text()) if path.is_file() else None
    return docs


def scrub(v):
    """``v`` with every absolute path (and relative one out of the repository) in its strings shortened as
    :func:`short_path` does."""
    if isinstance(v, dict):
        return {k: scrub(x) for k, x in v.items()}
    if isinstance(v, list):
        return [scrub(x) for x in v]
    if isinstance(v, str) and "/" in v:
        return re.sub(r"(?<![\w.~])(?:~?/|\.\./)[^\s\"',;]+", lambda m: short_path(m.group()), v)
    return v


def copy(results: Path, dest: Path) -> None:
    """Replace ``dest``'s JSON and PNG files by ``results``' figures and the plots the page shows."""
    dest.mkdir(parents=True, exist_ok=True)
    for old in [*dest.glob("*.json"), *dest.glob("*.png")]:
        old.unlink()
    for name, doc in load_all(results).items():
        if doc is not None:  # paths outside the repository (the user's data) as PATH/TO/<its last two parts>
            (dest / f"{name}.json").write_text(json.dumps(scrub(doc), indent=2) + "\n")
    for png, _ in (p for group in PLOTS.values() for p in group):
        src = results / png
        if not src.is_file() and png.startswith("node_latency_"):
            src = results / png.removesuffix(".png") / "latency.png"
        if src.is_file():
            shutil.copy(src, dest / png)


# ---------------------------------------------------------------------------------------------------- sections
REG_METHODS = {
    "as-they-come": ["deepbbs++", "deepbbs++paper", "deepbbs++fast", "gicp"],
    "45deg-5m": ["deepbbs++", "deepbbs++paper", "deepbbs++fast", "gicp"],
    "any-start": ["deepbbs++", "deepbbs++local", "deepbbs++paper", "deepbbs++fast", "gicp", "kiss-matcher",
                  "kiss-matcher+gicp"],
}
REG_LABELS = {"deepbbs++": "DeepBBS++ (shipped)", "deepbbs++paper": "DeepBBS++ paper (no GICP)",
              "deepbbs++fast": "DeepBBS++ fast preset", "deepbbs++local": "DeepBBS++ without its global search",
              "gicp": "small_gicp GICP", "kiss-matcher": "KISS-Matcher", "kiss-matcher+gicp": "KISS-Matcher + GICP"}
REG_TITLES = {"as-they-come": "As they come (no initial guess):", "45deg-5m": "Source moved by up to 45 deg / 5 m:",
              "any-start": "From any start (any yaw, up to 10 m):"}


def err(c: dict | None, digits: int = 3) -> str:
    if not c or (c.get("rot_deg_mean") is None and c.get("trans_m_mean") is None):
        return "-"
    return f"{num(c.get('rot_deg_mean'), digits)} / {num(c.get('trans_m_mean'), digits)}"


def reg_share(c: dict | None, notes: Notes) -> str:
    return "-" + notes.mark("no pair of this kind in the run") if not c else pct(c["success_pct"], c["cases"])


def reg_error(c: dict | None, notes: Notes) -> str:
    if c and c.get("success_pct") == 0:
        return "-" + notes.mark("no success, so no error to average")
    return err(c)


def registration(doc: dict | None, d: Path) -> list[str]:
    out = plots("registration", d) + command(doc)
    fig = (doc or {}).get("figures") or {}
    kiss_every = (fig.get("settings") or {}).get("kiss_every")
    for proto, methods in REG_METHODS.items():
        header = ["method", "real: success", "real: error deg / m", "sim: success", "sim: error deg / m",
                  "p50 / p95 ms (all)", "p50 / GICP's"]
        if proto == "any-start":
            header.append("p50 / KISS-Matcher + GICP's")
        out += [REG_TITLES[proto], ""]
        n = kiss_every or 3
        every = {1: "every case", 2: "every second case", 3: "every third case"}.get(n, f"every {n}th case")
        labels = [REG_LABELS[m] + (f" ({every})" if m.startswith("kiss") else "") for m in methods]
        groups = (fig.get("protocols") or {}).get(proto)
        if groups is None:
            out += not_run_table(header, labels) + [""]
            continue
        notes = Notes()
        rows = []
        for m, label in zip(methods, labels, strict=True):
            real, sim, all_ = ((groups.get(g) or {}).get(m) for g in ("real", "sim", "all"))
            if not (real or sim or all_):
                rows.append([label] + [NOT_RUN] * (len(header) - 1))
                continue
            a = all_ or {}
            gicp = "1" if m == "gicp" else ratio(a.get("p50_over_gicp"))
            row = [label, reg_share(real, notes), reg_error(real, notes), reg_share(sim, notes),
                   reg_error(sim, notes), f"{ms(a.get('p50_ms'))} / {ms(a.get('p95_ms'))}", gicp]
            if proto == "any-start":
                km = a.get("p50_over_kiss_matcher_gicp")
                row.append("1" if m == "kiss-matcher+gicp" else
                           ratio(km) if km is not None else "-" + notes.mark("KISS-Matcher + GICP not in the run"))
            rows.append(row)
        out += table(header, rows) + notes.lines() + [""]
        if proto == "any-start" and any(m.startswith("kiss") and (groups.get("all") or {}).get(m) for m in methods):
            out += [f"KISS-Matcher runs on {every} of this protocol's cases: its p50 / p95 are over those, the "
                    "others' over all of them; the last column compares p50s over KISS-Matcher's cases only.", ""]
    a = (((fig.get("protocols") or {}).get("any-start") or {}).get("all") or {}).get("deepbbs++") or {}
    km = a.get("p50_over_kiss_matcher_gicp")
    if not doc:
        out.append(f"Speed against KISS-Matcher from any start: {NOT_RUN}.")
        return out
    times = "- (KISS-Matcher + GICP not in the run)" if km is None else f"{km:.2f}"
    out.append(f"Speed against KISS-Matcher from any start: the shipped DeepBBS++'s p50 is {times} times KISS-Matcher"
               " + GICP's (the cases KISS-Matcher ran, same run; `p50_over_kiss_matcher_gicp` in `registration.json`).")
    return out


def verdict(doc: dict | None, d: Path) -> list[str]:
    out = plots("verdict", d)
    header = ["", "share", "registrations", "score"]
    labels = ["correct results accepted (shipped pipeline, every protocol)",
              "wrong poses rejected (shipped pipeline, every protocol)",
              "correct results accepted (without the global search, any start)",
              "wrong poses rejected (without the global search, any start)", "different places rejected"]
    v = ((doc or {}).get("figures") or {}).get("verdict")
    if v is None:
        return out + not_run_table(header, labels)
    notes = Notes()
    rows = []
    for m, kind in (("deepbbs++", "shipped pipeline, every protocol"),
                    ("deepbbs++local", "without the global search, any start")):
        c = v.get(m)
        if c is None:
            rows += [[f"correct results accepted ({kind})"] + [NOT_RUN] * 3,
                     [f"wrong poses rejected ({kind})"] + [NOT_RUN] * 3]
            continue
        rows.append([f"correct results accepted ({kind})",
                     pct(c["correct_accepted_pct"]) if c["correct"] else "-" + notes.mark("no correct result"),
                     str(c["correct"]), f"lowest {num(c['lowest_correct_score'], 3)}"])
        rows.append([f"wrong poses rejected ({kind})",
                     pct(c["wrong_rejected_pct"]) if c["wrong"] else "-" + notes.mark("no wrong pose in the run"),
                     str(c["wrong"]), f"highest {num(c['highest_wrong_score'], 3)}"])
    dp = v.get("different_places")
    rows.append(["different places rejected"] + ([NOT_RUN] * 3 if dp is None else [
        pct(dp["rejected_pct"]), str(dp["pairs"]),
        f"highest {num(dp['highest_score'], 3)}; p50 {ms(dp['p50_ms'])} ms per pair"]))
    return out + table(header, rows) + notes.lines()


# ---- the good start
GS_METHODS = [("gicp", "small_gicp GICP"), ("register", "`register(T_init)`"),
              ("good_start", "`register(T_init, good_start=True)`")]


def set_label(name: str) -> str:
    """good_start.json's data set key as words: kitti_00 -> KITTI 00 (real), sim_urban -> simulated urban."""
    if name.startswith("kitti_"):
        return f"KITTI {name.removeprefix('kitti_')} (real)"
    return "simulated " + name.removeprefix("sim_").replace("_", " ") if name.startswith("sim_") else name


def gs_cell(c: dict | None, anchor: bool) -> str:
    if not c:
        return NOT_RUN
    times = f"{ms(c.get('p50_ms'))} / {ms(c.get('p99_ms'))}; CPU {ms(c.get('cpu_mean_ms'))}"
    if anchor:
        return times
    rel = f"{ratio(c.get('p50_vs_gicp'))} / {ratio(c.get('p99_vs_gicp'))}; {ratio(c.get('cpu_mean_vs_gicp'))}"
    return f"{times} ({rel})"


def gs_goal(c: dict | None) -> str:
    if not c or c.get("p50_vs_gicp") is None:
        return "-"
    missed = [w for k, w in (("p50_vs_gicp", "p50"), ("p99_vs_gicp", "p99"), ("cpu_mean_vs_gicp", "CPU"))
              if c.get(k) is not None and c[k] > GOAL_GOOD_START]
    return "met" if not missed else f"missed: {', '.join(missed)} > {GOAL_GOOD_START:g} x GICP's"


def good_start(doc: dict | None, d: Path) -> list[str]:
    out = plots("good_start", d) + command(doc)
    header = ["raw pairs given a start", "pairs", "GICP: p50 / p99 ms; CPU ms",
              "`register(T_init)` (x GICP's)", "`good_start=True` (x GICP's)", "answered by GICP first", "goal"]
    wheader = ["starts slid along the road", "starts", "GICP alone: wrong", "`register(T_init)`: wrong accepted",
               "`good_start=True`: wrong accepted", "answered by GICP first", "goal"]
    fig = (doc or {}).get("figures") or {}
    tim, wrong = fig.get("timing"), fig.get("wrong_start")
    if tim is None:
        out += not_run_table(header, ["KITTI 00 (real)", "KITTI 02 (real)", "simulated scenes"]) + [""]
    else:
        rows = []
        for name, ms_ in tim.items():
            g, gs = ms_.get("gicp"), ms_.get("good_start")
            n = next((c["pairs"] for c in ms_.values() if c), None)
            first = "-" if not gs else pct(100 * (gs.get("paths") or {}).get("gicp", 0) / gs["pairs"])
            rows.append([set_label(name), str(n), gs_cell(g, True), gs_cell(ms_.get("register"), False),
                         gs_cell(gs, False), first, gs_goal(gs)])
        noise = fig.get("noise") or {}
        out += table(header, rows) + [
            "", f"Consecutive scans, each pair twice: from identity and from the truth moved by "
                f"{num(noise.get('trans_m'), 1)} m and {num(noise.get('yaw_deg'), 1)} deg. CPU: the mean per pair "
                "(this process and its children, read in ticks of 10 ms), the ratios in brackets p50 / p99; CPU.", ""]
    if wrong is None:
        out += not_run_table(wheader, ["every scene", "all"])
    else:
        rows = []
        for name, ms_ in wrong.items():
            if name == "calibration":
                continue
            g, r, gs = (ms_.get(m) or {} for m in ("gicp", "register", "good_start"))

            def acc(c):
                return "-" if not c else f"{c.get('accepted_wrong')} (rejected {c.get('rejected')})"
            first = "-" if not gs.get("cases") else pct(100 * (gs.get("paths") or {}).get("gicp", 0) / gs["cases"])
            ok = "-" if not gs or not r else ("met" if gs.get("accepted_wrong", 0) <= r.get("accepted_wrong", 0)
                                              else "missed: more wrong poses than `register(T_init)`")
            label = "all" if name == "all" else set_label(name) if name.startswith("kitti_") else name.replace("_", " ")
            gw = "-" if not g else f"{g.get('wrong')} ({pct(100 * (g.get('wrong_share') or 0))})"
            rows.append([label, str(g.get("cases", r.get("cases", "-"))), gw, acc(r), acc(gs), first, ok])
        shifts = ", ".join(f"{v:g}" for v in fig.get("shifts_m") or [])
        out += table(wheader, rows) + ["", f"Each pair's true pose slid {shifts} m forwards and backwards along the "
                                           "sensor's heading (GICP alone: the share and count of wrong poses; it has "
                                           "no verdict)."]
        cal = wrong.get("calibration")
        if cal:
            out += ["", calibration_line(cal)]
    return out


def calibration_line(cal: dict) -> str:
    v, s = cal.get("voxels") or {}, cal.get("sampled") or {}
    n, right = cal.get("converged"), cal.get("right")
    wrong = None if n is None or right is None else n - right
    return (f"Fitness alone (the share of points within `registration.verdict_dist` of the target, one of the "
            f"features the calibrated verdict reads), on the {n} answers of GICP within the good start's limits that "
            f"converged ({right} right, {wrong} wrong): on a spread subset of the source's GICP voxels a cut at "
            f"{num(v.get('threshold'), 3)} would take {v.get('wrong_accepted', '-')} wrong and reject "
            f"{v.get('right_rejected', '-')} right (highest wrong {num(v.get('wrong_max'), 3)}, lowest right "
            f"{num(v.get('right_min'), 3)}); on the sampled points, a cut at {num(s.get('threshold'), 3)}: highest "
            f"wrong {num(s.get('wrong_max'), 3)}, lowest right {num(s.get('right_min'), 3)}. The verdict's own "
            f"probabilities on GICP's answers from every family: `scripts/benchmarks/good_start_reach.py`.")


# ---- localization in a prior map
LOC_LABELS = {"maplocalizer": "DeepBBS++ (MapLocalizer)", "kiss-matcher+gicp": "KISS-Matcher + GICP",
              "fpfh-ransac+gicp": "FPFH + RANSAC + GICP"}
LOC_KINDS = {"same-lane": "same lane", "lane": "another lane", "reverse": "the other way"}


def map_label(name: str) -> str:
    return "real (KITTI and the reference pair, pooled)" if name == "real" else f"simulated {name.replace('_', ' ')}"


def loc_share(c: dict, key: str) -> str:
    return pct(None if c.get(key) is None else 100 * c[key])


def loc_time(c: dict) -> str:
    s50, s95 = c.get("time_s_p50"), c.get("time_s_p95")
    return f"{ms(None if s50 is None else 1e3 * s50)} / {ms(None if s95 is None else 1e3 * s95)}"


def loc_goal(c: dict) -> str:
    if not c or c.get("placed_share") is None:
        return "-"
    missed = [w for ok, w in ((100 * c["placed_share"] >= GOAL_LOC_PLACED_PCT, f"placed < {GOAL_LOC_PLACED_PCT:g} %"),
                              (not c.get("wrong_count"), "wrong poses"),
                              ((c.get("time_s_p50") or 0) <= GOAL_LOC_P50_S, f"p50 > {GOAL_LOC_P50_S:g} s"),
                              ((c.get("time_s_p95") or 0) <= GOAL_LOC_P95_S, f"p95 > {GOAL_LOC_P95_S:g} s"))
              if not ok]
    return "met" if not missed else "missed: " + ", ".join(missed)


def loc_exact_time(c: dict) -> str:
    """MapLocalizer's exact twin (GICP solved on one thread): its time p50 / p95, "-" when it did not run."""
    s50, s95 = c.get("exact_time_s_p50"), c.get("exact_time_s_p95")
    return "-" if s50 is None else f"{ms(1e3 * s50)} / {ms(None if s95 is None else 1e3 * s95)}"


def loc_row(label: str, c: dict | None, notes: Notes, with_goal: bool, exact: bool = False) -> list[str]:
    n = (6 if with_goal else 5) + exact
    if not c:
        return [label] + [NOT_RUN] * n
    if "note" in c:
        return [label] + ["-" + notes.mark(c["note"])] * n
    row = [label, pct(100 * c["placed_share"], c.get("queries")) if c.get("placed_share") is not None else "-",
           str(c.get("wrong_count", "-")), loc_share(c, "none_share"), loc_time(c)]
    if exact:
        row.append(loc_exact_time(c))
    timeouts = c.get("timeout_count")
    row[3] += notes.mark(f"{timeouts} timeout(s) among them") if timeouts else ""
    return row + [loc_goal(c)] if with_goal else row + [ms(1e3 * c["build_s"]) if c.get("build_s") else "-"]


BOOT_INTRO = ("From boot, the node's case: a query that gets no pose goes on with its drive's next scans (one "
              "every {step:g} s, up to {n}), each searched once it has arrived and the search before it has ended; "
              "the first pose published counts, its time from the query scan's arrival:")


def localization(doc: dict | None, d: Path) -> list[str]:
    out = plots("localization", d) + command(doc)
    header = ["map", "placed (queries)", "wrong accepted", "no pose", "first pose p50 / p95 ms", "goal"]
    eheader = [*header[:5], "one-thread GICP p50 / p95 ms", "goal"]  # MapLocalizer's exact twin beside
    bheader = ["map, method", "placed (queries)", "wrong accepted", "no pose", "first pose p50 / p95 ms",
               "map build ms"]
    kheader = ["query drives", "simulated urban", "simulated suburban", "simulated highway", "simulated open road"]
    sheader = ["map", "map length: first pose p50 ms (map points)"]
    fig = (doc or {}).get("figures")
    if fig is None:
        maps = ["simulated urban", "simulated suburban", "simulated highway", "simulated open road", "real (pooled)"]
        return (out + ["DeepBBS++ (MapLocalizer), every query:", ""] + not_run_table(eheader, maps) + [""]
                + [BOOT_INTRO.format(step=1.0, n=2), ""] + not_run_table(header, maps[:4]) + [""]
                + ["Beside the baselines, on the same queries (every third):", ""]
                + not_run_table(bheader, [f"{m}, {v}" for m in maps[:1] for v in LOC_LABELS.values()]) + [""]
                + ["MapLocalizer by kind of query:", ""] + not_run_table(kheader, [*LOC_KINDS.values(),
                                                                                  "repetitive places"]) + [""]
                + ["Time against the map's size:", ""] + not_run_table(sheader, maps[:4]))
    maps, pooled = fig.get("maps") or {}, fig.get("pooled") or {}
    notes = Notes()
    rows = [loc_row(map_label(k), (m.get("methods") or {}).get("maplocalizer"), notes, True, exact=True)
            for k, m in maps.items()]
    ml = pooled.get("maplocalizer") or {}
    if ml.get("sim"):
        rows.append(loc_row("all simulated maps", ml["sim"], notes, True, exact=True))
    if ml.get("all") and "real" in maps:
        rows.append(loc_row("all maps", ml["all"], notes, True, exact=True))
    out += ["DeepBBS++ (MapLocalizer), every query:", ""] + table(eheader, rows) + notes.lines() + [""]
    notes = Notes()
    rows = [loc_row(map_label(k), ((m.get("methods") or {}).get("maplocalizer") or {}).get("boot"), notes, True)
            for k, m in maps.items() if k != "real"]
    if ml.get("sim_boot"):
        rows.append(loc_row("all simulated maps", ml["sim_boot"], notes, True))
    if any(r[1] != NOT_RUN for r in rows):
        step = (fig.get("settings") or {}).get("boot_step", 1.0)
        n = (fig.get("settings") or {}).get("boot_scans", 2)
        out += [BOOT_INTRO.format(step=step, n=n), ""] + table(header, rows)
        out += notes.lines() + [""]
    every = (fig.get("settings") or {}).get("baseline_every")
    nth = {1: "every query", 2: "every second query", 3: "every third query"}.get(every, f"every {every}th query")
    notes = Notes()
    rows = []
    for k, m in maps.items():
        ms_ = m.get("methods") or {}
        for name, label in LOC_LABELS.items():
            c = ms_.get(name)
            if name == "maplocalizer" and c and c.get("baseline_subset"):
                c = {**c["baseline_subset"], "build_s": c.get("build_s")}
            if c is None and name not in ms_:
                continue
            rows.append(loc_row(f"{map_label(k).split(' (')[0]}, {label}", c, notes, False))
    out += [f"Beside the baselines, on the same queries ({nth}; each baseline registers the scan against the "
            "whole map):", ""] + table(bheader, rows) + notes.lines() + [""]
    sims = [k for k in maps if k != "real"]
    kheader = ["query drives", *(map_label(k) for k in sims)]
    rows = []
    for kind, label in LOC_KINDS.items():
        cells = []
        for k in sims:
            c = (((maps[k].get("methods") or {}).get("maplocalizer") or {}).get("by_kind") or {}).get(kind)
            cells.append("-" if not c else f"{pct(100 * c['placed_share'], c['queries'])}, wrong {c['wrong_count']}")
        rows.append([label, *cells])
    cells = []
    for k in sims:
        c = ((maps[k].get("methods") or {}).get("maplocalizer") or {}).get("repetitive")
        cells.append("-" if not c else f"{pct(100 * c['placed_share'], c['queries'])}, wrong {c['wrong_count']}")
    rows.append(["repetitive places (long straight stretches)", *cells])
    out += ["MapLocalizer by kind of query (placed, and wrong poses accepted):", ""] + table(kheader, rows) + [""]
    lengths = sorted({int(L) for k in sims for L in ((maps[k].get("scaling") or {}).get("by_map_length_m") or {})})
    if lengths:
        cols = sorted({round(L, -1) for L in lengths})
        sheader = ["map", *(f"{c} m" for c in cols)]
        rows = []
        for k in sims:
            by = (maps[k].get("scaling") or {}).get("by_map_length_m") or {}
            at = {round(int(L), -1): c for L, c in by.items()}
            rows.append([map_label(k), *("-" if at.get(c) is None else
                                         f"{ms(1e3 * at[c]['time_s_p50'])} ({at[c]['map_points']}), placed "
                                         f"{round(at[c]['placed_share'] * at[c]['queries'])} / {at[c]['queries']}, "
                                         f"wrong {at[c].get('wrong_count', 0)}" for c in cols)])
        n = len(((maps[sims[0]].get("scaling") or {}).get("queries")) or [])
        out += [f"Time against the map's size: the first {n} queries of each map against maps of the first metres "
                "of its drive (first pose p50 ms, the map's points in brackets; queries placed and wrong poses "
                "accepted):", ""]
        out += table(sheader, rows)
    return out


DESKEW = [("stream deskew", "stream deskew (default)"), ("raw", "raw"), ("pair deskew", "pair deskew"),
          ("compensated", "compensated (ceiling)"), ("gicp raw", "GICP from identity, raw")]


def deskew(doc: dict | None, d: Path) -> list[str]:
    out = plots("deskew", d) + command(doc)
    header = ["variant", "success", "error deg / m", "translation p95 m"]
    fig = (doc or {}).get("figures")
    if fig is None:
        return out + not_run_table(header, [label for _, label in DESKEW]) + [
            "", f"The stream deskew costs {NOT_RUN} ms per scan (p50)."]
    rows = []
    for key, label in DESKEW:
        a = (fig["variants"].get(key) or {}).get("all")
        rows.append([label] + ([NOT_RUN] * 3 if a is None else [
            pct(a["success_pct"], a["pairs"]), err(a, 4), num(a.get("trans_m_p95"), 4)]))
    p50 = (fig.get("stream_deskew_ms") or {}).get("p50")
    return out + table(header, rows) + ["", f"The stream deskew costs {ms(p50)} ms per scan (p50)."]


def odo_label(run: str) -> str:
    m = re.fullmatch(r"sim (\w+) (\d+)f (\S+)", run)
    if m:
        scene, frames, variant = m.groups()
        what = {"clean": "as it is", "drop": "8 gaps of dropped scans", "wrong-prior": "10 wrong priors"}
        return f"simulated {scene}, {frames} scans, {what.get(variant, variant)}"
    m = re.fullmatch(r"KITTI (\S+)", run)
    return f"KITTI {m.group(1)}" if m else run


def odo_cell(v: dict | None, m: str, notes: Notes) -> str:
    if v is None:
        return "-" + notes.mark(f"{m} not run on this variant (once it diverges a scan takes seconds)"
                                if m == "kiss-icp" else f"{m} not in the run")
    drift = num(v.get("kitti_t_err_pct"), 2)
    if v.get("kitti_t_err_pct") is None:
        drift += notes.mark("no segment of 100 m or longer: KITTI's drift is not defined")
    failed = v.get("failed_frames")
    return f"{drift} / {num(v.get('ate_rmse_m'), 3)}" + (notes.mark(f"{failed} failed frame(s)") if failed else "")


def odometry(doc: dict | None, d: Path) -> list[str]:
    out = plots("odometry", d) + command(doc)
    header = ["run", "scans", "DeepBBS++ drift % / ATE m", "KISS-ICP", "GICP",
              "DeepBBS++ frames/s (x KISS-ICP's)"]
    fig = (doc or {}).get("figures")
    if fig is None:
        return out + not_run_table(header, ["simulated urban, 500 scans, as it is",
                                            "simulated urban, 500 scans, 8 gaps of dropped scans",
                                            "simulated urban, 500 scans, 10 wrong priors", "KITTI 00", "KITTI 02"])
    notes = Notes()
    rows = []
    for run, r in fig["runs"].items():
        ms_ = r["methods"]
        dbb = ms_.get("deepbbs++") or {}
        fps = num(dbb.get("fps"), 1)
        if dbb.get("fps_over_kiss_icp") is not None:
            fps += f" ({ratio(dbb['fps_over_kiss_icp'])})"
        label = odo_label(run) + ("" if r.get("complete", True) else notes.mark("the run did not complete"))
        frames = dbb.get("frames") or next((v.get("frames") for v in ms_.values()), None)
        rows.append([label, str(frames) if frames is not None else "-",
                     *(odo_cell(ms_.get(m), m, notes) for m in ("deepbbs++", "kiss-icp", "gicp")), fps])
    return out + table(header, rows) + notes.lines()


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
    out = plots("node_latency_odometry", d) + command(doc)
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
    out = plots("node_latency_pair", d) + command(doc)
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
    out = plots("node_latency_localization", d) + command(doc)
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
    out = plots("kidnap", d) + command(doc)
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
    out = plots("first_contact", d) + command(doc)
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
    out = plots("busy", d) + command(doc)
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
    out = plots("decode", d) + command(doc)
    header = ["case", "median ms", "CPU median ms"]
    if doc is None:
        return out + not_run_table(header, ["xyz", "xyz + intensity, t, ring", "encode"])
    fig = doc["figures"]
    rows = [[case, num(c["median_ms"], 2), num(c.get("cpu_median_ms"), 2)] for case, c in fig["cases"].items()]
    return out + table(header, rows) + ["", f"{fig.get('points')} points ({fig.get('valid_points')} valid), "
                                            f"{fig.get('runs')} runs per case, goal {num(fig.get('goal_ms'), 1)} ms."]


def simulator(doc: dict | None, d: Path) -> list[str]:
    out = plots("simulator", d) + command(doc)
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
    out = plots("fleet", d) + command(doc)
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
    out = plots("threads", d) + command(doc)
    header = ["method", "1 thread: ms / frame", "every core: ms / frame", "1 thread / every core"]
    if doc is None:
        return out + not_run_table(header, ["deepbbs++", "gicp", "kiss-icp"])
    fig = doc["figures"]
    rows = [[f"`{m}`", num(c["one_thread_ms"], 1), num(c["every_core_ms"], 1), ratio(c["ratio"])]
            for m, c in fig["methods"].items()]
    frames = {c["frames"] for c in fig["methods"].values()}
    return out + table(header, rows) + ["", f"Medians over {', '.join(map(str, sorted(frames)))} frames per setting "
                                            f"({fig['rounds']} passes over the recording, the settings alternating)."]


def machine(docs: dict[str, dict | None], d: Path) -> list[str]:
    ran = {n: doc for n, doc in docs.items() if doc is not None}
    if not ran:
        return [f"{NOT_RUN}: no benchmark results in docs/benchmarks/ yet."]
    ms_ = {n: doc.get("machine") or {} for n, doc in ran.items()}
    out = []
    common = {}
    keys = ("cpus", "cpu_model", "platform", "python", "cpu_kernels")
    for k in keys:
        vals = {m.get(k) for m in ms_.values()}
        if len(vals) == 1 and None not in vals:
            common[k] = vals.pop()
    if common:
        model = f" ({common['cpu_model']})" if "cpu_model" in common else ""
        kernels = {"avx2": "; numpy, OpenBLAS and torch on their AVX2 kernels"}.get(common.get("cpu_kernels"), "")
        out += [f"{common.get('cpus', '-')} CPUs{model}, {common.get('platform', '-')}, Python "
                f"{common.get('python', '-')}{kernels}.", ""]
    own = [k for k in keys if k not in common]  # differing between the benchmarks: a column each
    labels = {"cpus": "CPUs", "cpu_model": "CPU", "platform": "platform", "python": "Python", "cpu_kernels": "kernels"}
    header = ["benchmark", "results written (UTC)", "load average (1 min)"] + [labels[k] for k in own]
    rows = []
    for n in BENCHMARKS:
        m = ms_.get(n)
        if m is None:
            rows.append([n, NOT_RUN, NOT_RUN] + [NOT_RUN] * (len(header) - 3))
            continue
        rows.append([n, m.get("date_utc") or "-", num(m.get("load_avg_1min"), 2)]
                    + [str(m.get(k, "-")) for k in own])
    return out + table(header, rows)


# ---------------------------------------------------------------------------------------------------- README
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


def section(name: str, docs: dict[str, dict | None], d: Path) -> list[str]:
    if name in ("machine", "readme"):
        return {"machine": machine, "readme": readme}[name](docs, d)
    if name == "sensor_defaults":  # docs/sensors.md: the rows of deepbbs_ros/core/sensors.py
        return _families_doc.sensor_defaults()
    doc = docs.get("registration") if name == "verdict" else docs.get(name)
    fn = {"registration": registration, "verdict": verdict, "deskew": deskew, "odometry": odometry,
          "node_latency_odometry": node_latency_odometry, "node_latency_pair": node_latency_pair,
          "first_contact": first_contact, "busy": busy, "decode": decode, "simulator": simulator,
          "fleet": fleet, "threads": threads, "good_start": good_start, "localization": localization,
          "node_latency_localization": node_latency_localization, "kidnap": kidnap,
          "families": lambda doc, d: _families_doc.families(doc, command(doc), NOT_RUN)}.get(name)
    if fn is None:
        raise SystemExit(f"render_docs.py: unknown marker bench:{name}")
    return fn(doc, d)


def render(text: str, docs: dict[str, dict | None], d: Path) -> str:
    def sub(m: re.Match) -> str:
        body = "\n".join(section(m.group(2), docs, d)).strip("\n")
        return f"{m.group(1)}\n{body}\n\n{m.group(4)}"

    return BLOCK.sub(sub, text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    p.add_argument("results", type=Path, help="a run_all.sh --out folder, or docs/benchmarks")
    p.add_argument("--copy", action="store_true", help="first replace docs/benchmarks/'s JSON and PNG files by the "
                   "results' (then render from docs/benchmarks/)")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 when a page is not the render")
    p.add_argument("--docs", type=Path, default=DOCS_BENCH, help=argparse.SUPPRESS)  # tests: another checkout
    args = p.parse_args(argv)
    if not args.results.is_dir():
        print(f"render_docs.py: {args.results} is not a folder", file=sys.stderr)
        return 2
    if args.copy and args.check:
        print("render_docs.py: --copy and --check exclude each other", file=sys.stderr)
        return 2
    docs_bench = args.docs.resolve()
    page, readme_path = docs_bench.parent / "benchmarks.md", docs_bench.parent.parent / "README.md"
    if args.copy:
        copy(args.results, docs_bench)
        args.results = docs_bench
    docs = load_all(args.results)
    stale = []
    sensors = docs_bench.parent / SENSORS_PAGE
    for path in (page, readme_path, *([sensors] if sensors.is_file() else [])):
        text = path.read_text()
        new = render(text, docs, docs_bench)
        if new == text:
            continue
        stale.append(path)
        if not args.check:
            path.write_text(new)
    ran = [n for n, doc in docs.items() if doc is not None]
    if args.check:
        if stale:
            print("render_docs.py: not a render of " + str(args.results) + ": "
                  + ", ".join(str(s.name) for s in stale)
                  + f" (run python scripts/benchmarks/render_docs.py {args.results})", file=sys.stderr)
            return 1
        print(f"render_docs.py: the pages are the render of {args.results} ({len(ran)} benchmark(s) with results)")
        return 0
    print(f"render_docs.py: rendered {', '.join(p.name for p in stale) or 'nothing new'} from {args.results} "
          f"(results: {', '.join(ran) or 'none'})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
