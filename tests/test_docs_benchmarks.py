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

REPO = Path(__file__).resolve().parents[1]
BENCH = REPO / "scripts" / "benchmarks"
PAGE = REPO / "docs" / "benchmarks.md"
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


def test_every_plot_shown_is_written_by_a_benchmark():
    shown = re.findall(r"!\[[^\]]*\]\(benchmarks/([\w.-]+\.png)\)", PAGE.read_text())
    assert shown, "docs/benchmarks.md shows no plot"
    code = "\n".join(p.read_text() for p in BENCH.iterdir() if p.suffix in (".py", ".sh"))
    missing = [name for name in shown if name not in code]
    assert not missing, f"docs/benchmarks.md shows plots no benchmark writes: {missing}"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_help_runs(script):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    cmd = ["bash", str(script), "--help"] if script.suffix == ".sh" else [sys.executable, str(script), "--help"]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr[-2000:]
    assert len(res.stdout.strip()) > 40, res.stdout


def test_relative_links_resolve():
    """Links in the model card, the architecture page and docs/benchmarks.md point at files of the repository
    (the benchmark plots excepted: they are the output of scripts/benchmarks/run_all.sh)."""
    bad = []
    for page in (REPO / "MODEL.md", REPO / "ARCHITECTURE.md", PAGE):
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#", 1)[0]).resolve()
            if page == PAGE and target.startswith("benchmarks/") and target.endswith(".png"):
                continue
            if not path.exists() or REPO not in path.parents:
                bad.append(f"{page.name}: {target}")
    assert not bad, bad
