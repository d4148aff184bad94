"""Lint runs as part of the test suite (ruff; rules and line length are fixed here)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUFF_ARGS = [
    "check",
    "--line-length", "120",
    "--select", "E,F,W,I,B",
    "--ignore", "B008,B905",
    "--target-version", "py310",
]  # fmt: skip
PATHS = ["deepbbs_ros", "msg_adapters", "tests", "scripts", "launch", "docs", "setup.py"]


def test_ruff_clean():
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    paths = [p for p in PATHS if (ROOT / p).exists()]
    proc = subprocess.run([ruff, *RUFF_ARGS, *paths], cwd=ROOT, capture_output=True, text=True)
    hint = f"fix with: ruff {' '.join(RUFF_ARGS)} --fix ."
    assert proc.returncode == 0, f"ruff found problems ({hint}):\n{proc.stdout}{proc.stderr}"
