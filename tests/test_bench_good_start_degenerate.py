"""scripts/benchmarks/good_start_degenerate.py: its starts are verdict.py's (calibrate_verdict.py ``collect``'s
``starts`` hook draws the same near and far starts as the rows do), and its tally counts each class per setting."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import calibrate_verdict as cv  # noqa: E402
import good_start_degenerate as bench  # noqa: E402

RIG = [("vlp16", "wheeled", "corridor")]


def test_the_starts_hook_draws_the_starts_the_rows_are_made_from(monkeypatch):
    hooked = []
    cv.collect(RIG, 39, 2, log=lambda *_: None, starts=lambda kind, s, t, T0, T_gt, ri: hooked.append((kind, T0)))
    seen, gicp = [], cv.good_start_gicp

    def spy(src_pc, tgt_pc, T_init, rc):
        seen.append(np.array(T_init))
        return gicp(src_pc, tgt_pc, T_init, rc)

    monkeypatch.setattr(cv, "good_start_gicp", spy)
    cv.collect(RIG, 39, 2, log=lambda *_: None)
    assert [k for k, _ in hooked] == ["near", "far", "far"] * 2
    # in order among the GICP runs of the rows (from the truth, the starts, another place): the same draws
    at = 0
    for _, T0 in hooked:
        at = next(i for i in range(at, len(seen)) if np.allclose(seen[i], T0)) + 1


def test_the_tally_counts_each_class_and_the_answers_lost():
    def row(fired, off, on, ms=(1000.0, 20.0)):
        return {"family": "solid", "kind": "far", "fired": fired,
                "off": {"class": off, "ms": ms[0]}, "on": {"class": on, "ms": ms[1]}}

    rows = [row(True, "right_valid", "not_right_not_valid"), row(True, "wrong_valid", "right_not_valid"),
            row(True, "right_not_valid", "right_not_valid", (500.0, 50.0)), row(False, "right_valid", "right_valid")]
    t = bench.tally(rows, True)["solid"]
    assert t["starts"] == 3 and t["differ"] == 2 and len(t["lost"]) == 1
    assert t["off"]["right_valid"] == 1 and t["off"]["wrong_valid"] == 1 and t["on"]["wrong_valid"] == 0
    assert t["on"]["right_not_valid"] == 2 and t["on"]["not_right_not_valid"] == 1
    assert t["ratio_on_off_p50"] == 0.02 and t["off"]["ms_p50"] == 1000.0
    assert bench.tally(rows, False)["solid"]["starts"] == 1
