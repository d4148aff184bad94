"""The README's "Python API" example runs as printed and registers the sample drive to its ground truth."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _python_api_snippet() -> str:
    text = (REPO / "README.md").read_text()
    section = text.split("\n## Python API\n", 1)[1].split("\n## ", 1)[0]
    m = re.search(r"```python\n(.*?)```", section, re.S)
    assert m, "README.md has no python block under '## Python API'"
    return m.group(1)


def test_readme_python_api_example_runs(tmp_path):
    code = _python_api_snippet()
    assert len([ln for ln in code.splitlines() if ln.strip()]) <= 12, code  # a short example stays short
    script = tmp_path / "example.py"
    script.write_text(code)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=300,
                         env=env)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("RegistrationResult(T_target_source=T(t=[") and "converged=True" in lines[0], lines
    assert len(lines[0]) < 600  # a short repr, not the gamma array
    m = re.fullmatch(r"([0-9.]+) m from the ground truth", lines[-1])
    assert m and float(m.group(1)) < 0.05, lines[-1]


def test_user_docs_speak_to_users():
    """README, MODEL.md, ARCHITECTURE.md and docs/ refer to nothing outside the repository (sessions, issue
    numbers, a team's files, other folders on the build machine)."""
    bad = re.compile(r"\b(this|last|previous|helper) session\b|\bissues? \d+|\bthe team's\b|\.\./shared|/work/", re.I)
    docs = [REPO / "README.md", REPO / "MODEL.md", REPO / "ARCHITECTURE.md", *sorted((REPO / "docs").rglob("*.md"))]
    found = [f"{p.relative_to(REPO)}:{i}: {line.strip()}" for p in docs
             for i, line in enumerate(p.read_text().splitlines(), 1) if bad.search(line)]
    assert not found, "\n".join(found)
    assert (REPO / "docs" / "CONVENTIONS.md").is_file()
    for name in ("README.md", "ARCHITECTURE.md"):
        assert "docs/CONVENTIONS.md" in (REPO / name).read_text(), name
