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

The sections' renders: _registration_doc.py (pairs, verdict, good start, deskew, odometry), _localization_doc.py,
_runtime_doc.py (live node, kidnap, start-up, busy computer, decode, simulator, fleet, threads), _readme_doc.py,
_families_doc.py; their shared formatting: _render_format.py.

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
from _localization_doc import localization  # noqa: E402
from _readme_doc import readme  # noqa: E402
from _registration_doc import deskew, good_start, odometry, registration, verdict  # noqa: E402
from _render_format import NOT_RUN, ROOT, command, num, short_path, table  # noqa: E402
from _runtime_doc import (  # noqa: E402
    busy,
    decode,
    first_contact,
    fleet,
    kidnap,
    node_latency_localization,
    node_latency_odometry,
    node_latency_pair,
    simulator,
    threads,
)

PAGE = ROOT / "docs" / "benchmarks.md"
SENSORS_PAGE = "sensors.md"  # docs/sensors.md: the per-family tables (bench:families), when the page exists
README = ROOT / "README.md"
DOCS_BENCH = ROOT / "docs" / "benchmarks"
BLOCK = re.compile(r"(<!-- bench:([\w-]+) -->\n)(.*?)(<!-- /bench -->)", re.S)
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


def plots(name: str, docs_bench: Path) -> list[str]:
    return [f"![{alt}](benchmarks/{png})\n" for png, alt in PLOTS.get(name, []) if (docs_bench / png).is_file()]


def section(name: str, docs: dict[str, dict | None], d: Path) -> list[str]:
    if name in ("machine", "readme"):
        return {"machine": machine, "readme": readme}[name](docs, d)
    if name == "sensor_defaults":  # docs/sensors.md: the rows of SENSORS in deepbbs_ros/config/preprocess.py
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
    return plots(name, d) + fn(doc, d)  # the section's plots first


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
