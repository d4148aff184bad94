"""When localization in a map accepts a pose (no ROS): the map verdict's probability, its second minimum, ambiguity.

Every answer in a map (a global search's, a probe's, tracking's, a hint's) is judged by the map verdict
(core/map_verdict.py): the probability that the pose is right, calibrated on simulated localizations in maps, against
``localization.min_probability`` (:func:`accepts`). A pose it accepts that the fit leaves free along a direction (a
narrow field of view, a corridor) is refused when GICP from it, moved both ways along that direction, finds another
minimum as good beyond a right pose's tolerance (:func:`second_minimum`, ``localization.second_minimum``): the map
verdict judges a pose by how the scan lies on the map there, and a handheld Livox Avia scan moved 1 m / 2 degrees
still lies within its distance of a dense crop (0.89-0.97 on the real loop); GICP from it falls back to the truth,
3.4 tolerances away, with a better fit. The global search's answer is left to its probes (core/place_search.py) and
checked only where none ran. The answer chosen is refused as ambiguous when another accepted answer far
enough away fits about as well (:func:`rivals`). ``config`` is the whole :class:`~deepbbs_ros.config.Config`;
``src`` the scan's PreprocessResult; answers are ``_Answer`` (core/localization_types.py). Used by
:class:`~deepbbs_ros.core.localization.MapLocalizer`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import map_verdict
from deepbbs_ros.core.localization_types import _Answer
from deepbbs_ros.core.second_minimum import STEPS, Ambiguity, check
from deepbbs_ros.core.verdict import good_start_points


def threshold(config: Config) -> float:
    """The probability an answer needs: ``localization.min_probability``."""
    return config.localization.min_probability


def probability(src: Any, crop: Any, T_map_scan: np.ndarray, config: Config) -> float:
    """The map verdict's probability that the scan ``src`` (PreprocessResult) lies at ``T_map_scan`` (4, 4), judged
    on the map crop ``crop`` (``_Crop``)."""
    return map_verdict.answer_probability(src, crop, T_map_scan, config)


def accepts(config: Config, prob: float) -> bool:
    """The map verdict's probability reaches ``localization.min_probability``."""
    return bool(np.isfinite(prob) and prob >= config.localization.min_probability)


def second_minimum(src: Any, crop: Any, T_map_scan: np.ndarray, config: Config, threads: int = 1) -> Ambiguity:
    """core/second_minimum.py's check of the scan ``src`` at ``T_map_scan`` (4, 4) on the map crop ``crop``: the
    verdict's points (a spread subset of the scan's GICP voxels, ``registration.good_start_points``), the precision
    stage's clouds and settings; checked where the fit leaves the pose freer than a wrong pose's distance
    (``second_minimum.STEPS[0]``, 2 tolerances: there, a pose that far off along its weakest direction moves the
    residuals of the plane matches by less than their tolerance, ``verdict_dist / 5``, which the map verdict's plane
    shares cannot see); not checked (``Ambiguity()``, or one with ``step`` 0) when ``localization.second_minimum``
    is off, either has no GICP cloud, or the fit pins the pose closer. Two GICP runs where it checks (their first two
    iterations where they come back), two nearest-neighbour searches where it does not."""
    rc = config.registration
    spc, tpc = getattr(src, "polish_cloud", None), getattr(crop.pre, "polish_cloud", None)
    if not config.localization.second_minimum or spc is None or tpc is None:
        return Ambiguity()
    spc, tpc = spc.complete(threads=threads), tpc.complete(threads=threads)
    T = np.linalg.solve(crop.T_map_place, np.asarray(T_map_scan, np.float64))
    return check(good_start_points(spc, rc), T, spc, tpc, rc, threads, loose=STEPS[0], crop=True)


def accepts_pose(src: Any, crop: Any, T_map_scan: np.ndarray, config: Config, prob: float | None = None) -> bool:
    """The map verdict accepts the scan at ``T_map_scan`` on ``crop`` (:func:`accepts`; ``prob``: its probability
    when known) and the pose has no second minimum as good (:func:`second_minimum`)."""
    prob = probability(src, crop, T_map_scan, config) if prob is None else prob
    return accepts(config, prob) and not second_minimum(src, crop, T_map_scan, config).ambiguous


def rivals(best: _Answer, pool: list[_Answer], config: Config) -> list[_Answer]:
    """The answers of ``pool`` (``best`` among them) that make ``best`` ambiguous: accepted ones, fitting within
    ``ambiguity_margin`` of its score (a probe's: ``ambiguity_probe_margin``) and more than ``ambiguity_distance``
    away (a probe's: half ``ambiguity_probe``, at least 0.5 m)."""
    lc = config.localization
    return [a for a in pool if a is not best and a.ok and a.score >= best.score - (
                lc.ambiguity_probe_margin if a.probe else lc.ambiguity_margin)
            and np.linalg.norm(a.T[:3, 3] - best.T[:3, 3]) > (
                max(0.5, 0.5 * lc.ambiguity_probe) if a.probe else lc.ambiguity_distance)]
