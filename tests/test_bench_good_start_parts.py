"""families.py --parts (scripts/benchmarks/_good_start_parts.py): each part's CPU time read by wrapping its function,
the functions restored after, the pairs' medians summarised."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))

import _good_start_parts as parts  # noqa: E402

from deepbbs_ros.core import good_start, visibility  # noqa: E402
from deepbbs_ros.core.registration import DeepBBSRegistration  # noqa: E402


def test_every_part_is_wrapped_while_measured_and_restored_after():
    before = good_start._probability, visibility._target, DeepBBSRegistration.preprocess
    assert "preprocess" not in vars(DeepBBSRegistration)  # inherited: restored by removing the wrapper
    acc: dict[str, float] = {}
    with parts._wrapped(acc):
        assert good_start._probability is not before[0] and visibility._target is not before[1]
        assert "preprocess" in vars(DeepBBSRegistration)
        good_start._probability(type("P", (), {"applied": False})(), "", None, None, None)  # 0: not taken
    assert acc["verdict"] >= 0.0 and set(acc) == {"verdict"}
    assert (good_start._probability, visibility._target, DeepBBSRegistration.preprocess) == before
    assert "preprocess" not in vars(DeepBBSRegistration)


def test_the_summary_is_the_p50_over_pairs_of_each_pairs_median():
    recs = [{"parts": {"good_total": [3.0, 1.0, 2.0], "verdict": [1.0, 1.0, 4.0]}},
            {"parts": {"good_total": [5.0, 6.0, 7.0], "verdict": [0.5, 0.5, 0.5]}},
            {"parts": {"good_total": [9.0, 9.0, 9.0], "verdict": [2.0, 2.0, 2.0]}}]
    assert parts.summary(recs) == {"good_total": 6.0, "verdict": 1.0}
    assert parts.summary(recs + [{}]) == {}
