"""scripts/benchmarks/sweep_skew.py: the skew check end to end on raw simulated Livox sweeps, off and on, counted on
the same pairs (the counts of both settings cover the same answers)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts" / "benchmarks"))

import sweep_skew as bench  # noqa: E402


def test_one_pair_each_way_off_and_on(tmp_path):
    assert bench.main(["--rigs", "mid360:legged:hall", "--pairs", "1", "--out", str(tmp_path)]) == 0
    figures = json.loads((tmp_path / "sweep_skew.json").read_text())["figures"]["mid360:legged:hall"]
    for way in ("pipeline", "good_start"):
        c = figures["counts"][way]
        off, on = (sum(v for k, v in c.items() if k.endswith(end)) for end in ("_off", "_on"))
        assert off == on == 1
