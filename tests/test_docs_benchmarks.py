"""The model card, the architecture page and docs/benchmarks.md stay short, true to the repository and runnable:
size limits, every benchmark script named in docs/benchmarks.md exists (and every one there is named), each
script's --help runs, every plot the page shows is one a benchmark writes, and relative links resolve."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "scripts" / "benchmarks"
PAGE = REPO / "docs" / "benchmarks.md"
RENDER = BENCH / "render_docs.py"
README = REPO / "README.md"
SCRIPTS = sorted(p for p in BENCH.iterdir() if p.suffix in (".py", ".sh") and not p.name.startswith("_"))


@pytest.mark.parametrize("name", ["MODEL.md", "ARCHITECTURE.md"])
def test_short_pages(name):
    assert (REPO / name).stat().st_size <= 8 * 1024, f"{name} is over 8 KB"


def test_benchmark_scripts_named_both_ways():
    text = PAGE.read_text()
    named = set(re.findall(r"scripts/benchmarks/([\w.-]+\.(?:py|sh))", text))
    assert named, "docs/benchmarks.md names no script"
    missing = sorted(n for n in named if not (BENCH / n).is_file())
    assert not missing, f"docs/benchmarks.md names scripts that do not exist: {missing}"
    unnamed = sorted(p.name for p in SCRIPTS if p.name not in named)
    assert not unnamed, f"scripts/benchmarks/ holds scripts docs/benchmarks.md does not name: {unnamed}"
    assert not [p.name for p in (REPO / "scripts").glob("bench_*.py")], "benchmarks belong in scripts/benchmarks/"


def test_every_plot_shown_is_committed_and_written_by_a_benchmark():
    """The page shows a plot only when it is in docs/benchmarks/ (the render's rule), and every plot the renderer
    can show is one a benchmark writes."""
    shown = re.findall(r"!\[[^\]]*\]\(benchmarks/([\w.-]+\.png)\)", PAGE.read_text())
    assert sorted(shown) == sorted(p.name for p in (REPO / "docs" / "benchmarks").glob("*.png")), shown
    import render_docs

    code = "\n".join(p.read_text() for p in BENCH.iterdir() if p.suffix in (".py", ".sh") and p.name != RENDER.name)
    plots = [png for group in render_docs.PLOTS.values() for png, _ in group]
    missing = [name for name in plots if name not in code]
    assert not missing, f"render_docs.py shows plots no benchmark writes: {missing}"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_runs(script):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    cmd = ["bash", str(script), "--help"] if script.suffix == ".sh" else [sys.executable, str(script), "--help"]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    assert len(res.stdout.strip()) > 40, res.stdout


def test_relative_links_resolve():
    """Links in the model card, the architecture page and docs/benchmarks.md point at files of the repository."""
    bad = []
    for page in (REPO / "MODEL.md", REPO / "ARCHITECTURE.md", PAGE):
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#", 1)[0]).resolve()
            if not path.exists() or REPO not in path.parents:
                bad.append(f"{page.name}: {target}")
    assert not bad, bad


# ------------------------------------------------------------------------------------ the figures are a render
def _render(*args, cwd=REPO) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, str(RENDER), *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=120, env=env)


def test_pages_are_the_render_of_the_committed_results():
    """Every figure of docs/benchmarks.md and of the README's Results table is the render of docs/benchmarks/*.json
    (none there: every table says not run)."""
    res = _render("docs/benchmarks", "--check")
    assert res.returncode == 0, res.stdout + res.stderr


def _tables_outside_markers(text: str) -> list[str]:
    import render_docs

    rest = render_docs.BLOCK.sub("", text)
    return [line for line in rest.splitlines() if line.startswith("|")]


def test_no_figure_outside_the_markers():
    """No TBD and no hand-made figure table: outside the bench markers the page has only the table of scripts,
    the README's Results table is inside them."""
    page = PAGE.read_text()
    assert "TBD" not in page
    outside = _tables_outside_markers(page)
    assert outside and outside[0].startswith("| benchmark | script |"), outside[:1]
    assert all("scripts/benchmarks/" in line for line in outside[2:]), outside
    results = README.read_text().split("## Results", 1)[1].split("\n## ", 1)[0]
    assert "<!-- bench:readme -->" in results and "TBD" not in results
    assert not _tables_outside_markers(results)
    for anchor in ("Registration of raw pairs", "Odometry", "Live node latency", "A fleet of recordings on Ray",
                   "Machine", "The verdict"):
        assert f"\n## {anchor}\n" in page, anchor


def _doc(figures: dict, command: str) -> dict:
    return {"command": command, "machine": {"cpus": 2, "platform": "Linux-x", "python": "3.11.7",
                                            "load_avg_1min": 0.25, "date_utc": "2026-01-01T00:00:00Z"},
            "figures": figures}


def test_render_copy_and_check(tmp_path):
    """--copy replaces docs/benchmarks/ by a run's results and renders them with the fixed formatting; a benchmark
    that did not run says so (no older figure stays), a plot is shown only when copied, and --check catches a
    hand-edited figure."""
    import json
    import shutil

    repo = tmp_path / "repo"
    (repo / "docs" / "benchmarks").mkdir(parents=True)
    shutil.copy(PAGE, repo / "docs" / "benchmarks.md")
    shutil.copy(README, repo / "README.md")
    out = tmp_path / "out"
    (out / "logs").mkdir(parents=True)
    (out / "decode.json").write_text(json.dumps(_doc(
        {"points": 131072, "valid_points": 123686, "runs": 5, "goal_ms": 5.0,
         "cases": {"decode xyz": {"median_ms": 1.0457849, "cpu_median_ms": 0.97294}}},
        f"scripts/benchmarks/decode.py --runs 5 --out {out}")))
    (out / "decode.png").write_bytes(b"png")
    (out / "node_latency_pair").mkdir()
    recs = [{"layout": "velodyne", "stream": "consecutive", "run": "1 (00)", "busy": False, "method": m, "pairs": 20,
             "answered": 1.0, "p50_ms": p50, "p99_ms": p99, "error": "", "cpu": "", "diagnostics": {"x": "1"},
             "samples": [{"period": 0, "latency_ms": 1.0}]} for m, p50, p99 in (("deepbbs", 64.0, 90.2),
                                                                                 ("gicp", 80.0, 145.4))]
    (out / "node_latency_pair" / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    (out / "logs" / "node_latency_pair.command").write_text("scripts/benchmarks/node_latency.py --mode pair\n")
    docs = repo / "docs" / "benchmarks"
    (docs / "fleet.json").write_text("{}")  # an older result: gone after the copy
    res = _render(out, "--copy", "--docs", docs)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in docs.iterdir()) == ["decode.json", "decode.png", "node_latency_pair.json"]
    kept = json.loads((docs / "node_latency_pair.json").read_text())
    assert kept["command"] == "scripts/benchmarks/node_latency.py --mode pair"
    assert "samples" not in kept["figures"]["runs"][0] and "diagnostics" not in kept["figures"]["runs"][0]
    page = (repo / "docs" / "benchmarks.md").read_text()
    assert "| decode xyz | 1.05 | 0.97 |" in page
    assert "Measured by `python scripts/benchmarks/decode.py --runs 5 --out PATH/TO/" in page
    assert "![Median time per case against the goal](benchmarks/decode.png)" in page
    assert "benchmarks/fleet.png" not in page and "benchmarks/node_latency_pair.png" not in page
    assert "| consecutive scans, run 1 (00) | 100.0 % (20), 64 / 90 | 100.0 % (20), 80 / 145 | x0.80 | met |" in page
    fleet = page.split("<!-- bench:fleet -->", 1)[1].split("<!-- /bench -->", 1)[0]
    assert "| `gicp` |" not in fleet and "not run" in fleet
    readme = (repo / "README.md").read_text()
    assert "100.0 % or more" not in readme and "| 100.0 %, 64 / 90 ms | GICP node: 100.0 %, 80 / 145 ms |" in readme
    assert _render(docs, "--check", "--docs", docs).returncode == 0
    (repo / "docs" / "benchmarks.md").write_text(page.replace("| decode xyz | 1.05 |", "| decode xyz | 1.04 |"))
    res = _render(docs, "--check", "--docs", docs)
    assert res.returncode == 1 and "benchmarks.md" in res.stderr


def test_render_good_start_localization_and_node_localization(tmp_path):
    """The three newer sections render their figures: the good start against GICP with its goal, localization per
    map with its goal, and the node in localization mode against the anchor (p50 / p99 / CPU ratios, paths)."""
    import json
    import shutil

    repo = tmp_path / "repo"
    (repo / "docs" / "benchmarks").mkdir(parents=True)
    shutil.copy(PAGE, repo / "docs" / "benchmarks.md")
    shutil.copy(README, repo / "README.md")
    out = tmp_path / "out"
    out.mkdir()
    c = {"pairs": 4, "p50_ms": 100.0, "p99_ms": 120.0, "cpu_p50_ms": 50.0, "cpu_mean_ms": 50.0, "paths": {"gicp": 4}}
    timing = {"kitti_00": {"gicp": {**c, "p50_vs_gicp": 1.0, "p99_vs_gicp": 1.0, "cpu_mean_vs_gicp": 1.0},
                           "good_start": {**c, "p50_ms": 105.0, "p50_vs_gicp": 1.05, "p99_vs_gicp": 1.2,
                                          "cpu_mean_vs_gicp": 0.9}}}
    w = {"cases": 10, "accepted_right": 10, "accepted_wrong": 0, "rejected": 0, "paths": {"deepbbs": 10}}
    wrong = {k: {"gicp": {"cases": 10, "right": 8, "wrong": 2, "wrong_share": 0.2}, "register": w, "good_start": w}
             for k in ("urban", "all")}
    (out / "good_start.json").write_text(json.dumps(_doc({"noise": {"trans_m": 0.2, "yaw_deg": 1.0},
                                                          "shifts_m": [2.0], "timing": timing, "wrong_start": wrong},
                                                         "scripts/benchmarks/good_start.py")))
    s = {"queries": 10, "placed_share": 1.0, "wrong_share": 0.0, "none_share": 0.0, "wrong_count": 0,
         "time_s_p50": 0.5, "time_s_p95": 0.9, "exact_time_s_p50": 0.7, "exact_time_s_p95": 1.4}
    (out / "localization.json").write_text(json.dumps(_doc(
        {"maps": {"urban": {"methods": {"maplocalizer": {**s, "build_s": 0.5}}}}, "pooled": {},
         "settings": {"baseline_every": 3}}, "scripts/benchmarks/localization.py")))
    (out / "node_latency_localization").mkdir()
    recs = [{"layout": "velodyne", "stream": "consecutive", "run": "1", "busy": False, "method": m, "pairs": 100,
             "answered": 1.0, "p50_ms": p50, "p99_ms": p99, "error": "", "cpu": "", "cpu_ms": cpu,
             "diagnostics": {"paths.gicp": g, "paths.deepbbs": "1", "paths.search": "0"}}
            for m, p50, p99, cpu, g in (("deepbbs", 50.0, 100.0, 60.0, "99"), ("gicp", 40.0, 200.0, 50.0, "0"))]
    (out / "node_latency_localization" / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    docs = repo / "docs" / "benchmarks"
    res = _render(out, "--copy", "--docs", docs)
    assert res.returncode == 0, res.stderr
    page = (repo / "docs" / "benchmarks.md").read_text()
    assert "| KITTI 00 (real) | 4 | 100 / 120; CPU 50 | not run | 105 / 120; CPU 50 (x1.05 / x1.20; x0.90) | " \
           "100.0 % | missed: p99 > 1.1 x GICP's |" in page
    assert "| urban | 10 | 2 (20.0 %) | 0 (rejected 0) | 0 (rejected 0) | 0.0 % | met |" in page
    assert "| simulated urban | 100.0 % (10) | 0 | 0.0 % | 500 / 900 | 700 / 1400 | met |" in page
    assert "| HDL-64E layout, run 1 | 100.0 % (100), 50 / 100 | 100.0 % (100), 40 / 200 | x1.25 / x0.50 / x1.20 " \
           "(60 ms) | 99 / 1 / 0 | missed: p50 > 1.2 x the anchor's |" in page
    readme = (repo / "README.md").read_text()
    assert "| x1.05 / x1.20 / x0.90; 0 wrong |" in readme
    assert _render(docs, "--check", "--docs", docs).returncode == 0


def test_paths_outside_the_repository_are_shortened():
    """A recorded command's paths outside the repository (the user's data), absolute or relative, read PATH/TO/...;
    the repository's own stay as they are."""
    import render_docs

    assert render_docs.short_path("../data/kitti/00") == "PATH/TO/kitti/00"
    assert render_docs.short_path("/mnt/data/kitti/02") == "PATH/TO/kitti/02"
    assert render_docs.short_path(str(REPO / "bags" / "x.mcap")) == "bags/x.mcap"
    assert render_docs.short_path("scripts/benchmarks/localization.py") == "scripts/benchmarks/localization.py"
    assert render_docs.scrub({"command": "x.py --kitti ../data/kitti/00 --out /tmp/run/out"}) == {
        "command": "x.py --kitti PATH/TO/kitti/00 --out PATH/TO/run/out"}
    assert render_docs.scrub({"cache": "~/.cache/deepbbs_ros/bench"}) == {"cache": "PATH/TO/deepbbs_ros/bench"}
