"""When localization in a map accepts a pose (no ROS): the map verdict's probability and ambiguity.

Every answer in a map (a global search's, a probe's, tracking's, a hint's) is judged by the map verdict
(core/map_verdict.py): the probability that the pose is right, calibrated on simulated localizations in maps, against
``localization.min_probability`` (:func:`accepts`). The answer chosen is refused as ambiguous when another accepted
answer far enough away fits about as well (:func:`rivals`). ``config`` is the whole
:class:`~deepbbs_ros.config.Config`; ``src`` the scan's PreprocessResult; answers are ``_Answer``
(core/localization_types.py). Used by :class:`~deepbbs_ros.core.localization.MapLocalizer`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core import map_verdict
from deepbbs_ros.core.localization_types import _Answer


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


def rivals(best: _Answer, pool: list[_Answer], config: Config) -> list[_Answer]:
    """The answers of ``pool`` (``best`` among them) that make ``best`` ambiguous: accepted ones, fitting within
    ``ambiguity_margin`` of its score (a probe's: ``ambiguity_probe_margin``) and more than ``ambiguity_distance``
    away (a probe's: half ``ambiguity_probe``, at least 0.5 m)."""
    lc = config.localization
    return [a for a in pool if a is not best and a.ok and a.score >= best.score - (
                lc.ambiguity_probe_margin if a.probe else lc.ambiguity_margin)
            and np.linalg.norm(a.T[:3, 3] - best.T[:3, 3]) > (
                max(0.5, 0.5 * lc.ambiguity_probe) if a.probe else lc.ambiguity_distance)]
