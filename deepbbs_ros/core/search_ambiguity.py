"""The global search's answer weighed against the other poses its candidates reached (no ROS).

The verdict's probability is that of one pose being right, judged alone. The search (core/global_search.py) takes
several candidates through the precision stage and the verdict; two of them further apart than a wrong pose's
tolerance (2 degrees or 0.5 m) cannot both be right, so where both look right the scene is ambiguous to the verdict
(a symmetric place and its 180-degree flip, a corridor seen from either end). A rival is another candidate the
verdict and the search would accept alone (valid: probability ``p_other`` at least ``registration.verdict_probability``,
no second minimum as good, not bent by its sweeps, a fitness of ``registration.search_min_score``); of two such
exclusive poses, the answer (``p``) is right with probability at most ``p / (p + p_other)``, under 0.6 (p <= 1), so
the answer is not valid (``registration.search_ambiguity``). A less probable candidate does not count: the calibrated
probability of a wrong pose reaches 0.6 in a courtyard 90 degrees off, where the right one scores 1.0. Nothing is
fitted: the bar is the verdict's own.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.coarse_rescue import moved

__all__ = ["WRONG_DEG", "WRONG_M", "distinct", "rival", "settle", "weigh", "weighed"]

WRONG_DEG, WRONG_M = 2.0, 0.5  # two poses further apart than this cannot both be right (the goal's wrong pose)


def weighed(st: Any, rc: Any) -> bool:
    """Whether the given start's valid answer that is not sure (``st``, a registration state) is weighed against the
    search's candidates, as a search answer is (core/global_search.py ``retry``): with
    ``registration.search_ambiguity``, unless the caller vouched for the start (``register(..., good_start=True)``)
    and the answer stayed within the good start's limits of it (``registration.good_start_max_*``): a stream of good
    starts pays nothing more."""
    if not rc.search_ambiguity:
        return False
    if not st.vouched:
        return True
    trans, rot = moved(st.T_start, st.T)
    return trans > rc.good_start_max_trans or rot > rc.good_start_max_rot_deg


def settle(best: Any, seen: list, rc: Any) -> Any:
    """The search's answer ``best`` (a registration state), not valid where a candidate of ``seen`` makes it ambiguous
    (:func:`weigh`, with ``registration.search_ambiguity``; ``best.rival`` says why)."""
    if rc.search_ambiguity and best.valid:
        best.valid, best.rival = weigh(best, seen, rc)
    return best


def distinct(A: np.ndarray, B: np.ndarray) -> bool:
    """Two poses (4, 4) further apart than :data:`WRONG_DEG` degrees or :data:`WRONG_M` m."""
    trans, rot = moved(A, B)
    return rot > WRONG_DEG or trans > WRONG_M


def rival(best: Any, seen: list, rc: Any) -> Any:
    """The most probable of the candidates ``seen`` (registration states after the verdict and the search's fitness
    floor) distinct from ``best`` that are valid (the verdict and the search would take them alone), or None."""
    out = None
    for c in seen:
        if c is best or not c.valid or not distinct(best.T, c.T):
            continue
        if out is None or c.probability > out.probability:
            out = c
    return out


def weigh(best: Any, seen: list, rc: Any) -> tuple[bool, str]:
    """Whether ``best`` (valid) stays valid against its :func:`rival` among ``seen``: ``p / (p + p_other)`` reaches
    ``registration.verdict_probability``. -> (stays valid, "" or why not)."""
    other = rival(best, seen, rc)
    if other is None:
        return True, ""
    p, q = float(best.probability), float(other.probability)
    share = p / (p + q) if p + q > 0 else 0.0
    if share >= rc.verdict_probability:
        return True, ""
    trans, ang = moved(best.T, other.T)
    return False, (f"ambiguous: a second pose {ang:.1f} deg / {trans:.2f} m away at probability "
                   f"{q:.2f} (this one {p:.2f}: at most {share:.2f} of being right)")
