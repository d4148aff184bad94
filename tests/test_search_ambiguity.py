"""The global search's answer weighed against its other candidates (core/search_ambiguity.py).

Two poses further apart than a wrong pose's tolerance cannot both be right: an answer whose rival is about as
probable is not valid (P(right) at most p / (p + p_other)); a rival the search would not take (a fitness under
``registration.search_min_score``, a sweep that bends it) or one within the tolerance does not count.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import search_ambiguity
from deepbbs_ros.replay.synthetic import pose


def cand(T: np.ndarray, p: float, score: float = 0.5, skew: str = "") -> SimpleNamespace:
    return SimpleNamespace(T=T, probability=p, score=score, skew=skew, valid=p >= 0.7)


def test_distinct_is_the_wrong_pose_tolerance():
    T = pose(3.0, -1.0, 0.2, np.radians(20.0))
    assert not search_ambiguity.distinct(T, T @ pose(0.4, 0.0, 0.0, np.radians(1.5)))
    assert search_ambiguity.distinct(T, T @ pose(0.6, 0.0, 0.0, 0.0))
    assert search_ambiguity.distinct(T, T @ pose(0.0, 0.0, 0.0, np.radians(2.5)))
    assert search_ambiguity.distinct(T, T @ pose(0.0, 0.0, 0.0, np.pi))  # the flip


def test_a_flip_as_probable_makes_the_answer_ambiguous():
    """A half turn about the sensor as probable as the answer (a place symmetric about it): neither can be trusted;
    a rival far less probable leaves the answer valid, p / (p + p_other) against verdict_probability (0.7)."""
    rc = Config().registration
    T = pose(1.0, 2.0, 0.0, np.radians(35.0))
    flip = T @ pose(0.0, 0.0, 0.0, np.pi)
    best = cand(T, 0.93)
    ok, why = search_ambiguity.weigh(best, [best, cand(flip, 0.88)], rc)
    assert not ok and why.startswith("ambiguous: a second pose 180.0 deg")
    ok, why = search_ambiguity.weigh(best, [best, cand(flip, 0.3)], rc)  # 0.93 / 1.23 = 0.76
    assert ok and why == ""
    ok, _ = search_ambiguity.weigh(best, [best, cand(flip, 0.45)], rc)  # 0.93 / 1.38 = 0.67
    assert not ok


def test_rivals_the_search_would_not_take_do_not_count():
    """A flip that lays the ground on the ground (fitness under search_min_score), a pose the skew check turned away,
    and the answer itself moved within the tolerance are no rivals."""
    rc = Config().registration
    T = pose(0.0, 0.0, 0.0, 0.0)
    best = cand(T, 0.9)
    seen = [best, cand(T @ pose(0.0, 0.0, 0.0, np.pi), 0.92, score=rc.search_min_score / 2),
            cand(T @ pose(3.0, 0.0, 0.0, 0.0), 0.95, skew="rejected: sweep skew"),
            cand(T @ pose(0.2, 0.0, 0.0, np.radians(1.0)), 0.99)]
    assert search_ambiguity.rival(best, seen, rc) is None
    assert search_ambiguity.weigh(best, seen, rc) == (True, "")
