"""scripts/benchmarks/good_start_reach.py: which GICP answers each acceptance rule takes, and the summary, on
hand-made cases."""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts" / "benchmarks"))

import good_start_reach as reach  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402


def _case(rot, trans, prob, moved_deg=5.0, moved_m=1.0, iterations=5, applied=True, start="identity"):
    return {"set": "s", "i": 1, "j": 0, "start": start, "applied": applied, "iterations": iterations,
            "moved_m": moved_m, "moved_deg": moved_deg, "rot": rot, "trans": trans, "prob": prob}


def test_the_verdict_rule_takes_what_the_verdict_accepts_however_far_gicp_moved():
    rc = Config().registration
    far = _case(0.2, 0.05, 0.9, moved_deg=35.0, iterations=38)  # right, turned 35 deg in 38 iterations
    assert reach.takes("verdict", far, rc) and not reach.takes("capped", far, rc)
    near = _case(0.2, 0.05, 0.9)
    assert reach.takes("verdict", near, rc) and reach.takes("capped", near, rc)
    sure = _case(0.2, 0.05, 0.97, moved_deg=15.0)  # within twice the limits: the capped rule wanted it sure
    assert reach.takes("capped", sure, rc) and not reach.takes("capped", _case(0.2, 0.05, 0.9, moved_deg=15.0), rc)
    assert not reach.takes("verdict", _case(0.2, 0.05, 0.5), rc)
    assert not reach.takes("verdict", _case(0.2, 0.05, 0.9, applied=False), rc)  # not converged


def test_the_summary_counts_right_and_wrong_answers_and_the_probabilities_between_them():
    rc = Config().registration
    recs = [_case(0.2, 0.05, 0.9, moved_deg=35.0), _case(30.0, 4.0, 0.2, start="30 deg / 2 m"),
            _case(1.5, 0.1, 0.8), _case(0.3, 0.1, 0.4, start="30 deg / 2 m")]
    assert [reach.kind(r) for r in recs] == ["right", "wrong", "between", "right"]
    fig = reach.summarise(recs, rc)
    assert fig["cells"]["all all"] == {"right": 2, "wrong": 1, "between": 1, "verdict_right": 1, "capped_right": 0,
                                       "verdict_wrong": 0, "capped_wrong": 0, "verdict_between": 1,
                                       "capped_between": 1}
    assert fig["cells"]["s moved"]["wrong"] == 1 and fig["cells"]["s identity"]["right"] == 1
    assert fig["highest_wrong_probability"] == 0.2 and fig["lowest_right_probability"] == 0.4
    assert fig["right_under_threshold"] == 1
