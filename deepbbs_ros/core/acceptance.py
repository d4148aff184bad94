"""When global localization accepts a pose (no ROS): the map's bar, sharpness, agreement and ambiguity.

A registration's answer on a candidate place is accepted by the verdict and ``localization.min_score``
(:func:`accepts`); under that bar it still counts when it is sharp (:func:`sharp`: of the scan points the map
covers, most fit closely) or when two places' answers agree on it (:func:`agreed`); it is refused as ambiguous when
another answer far enough away scores and fits about as well (:func:`rivals`). ``config`` is the whole
:class:`~deepbbs_ros.config.Config`; ``registration`` the localizer's (its GICP threads); ``src`` the scan's
PreprocessResult; answers are ``_Answer`` (core/localization_types.py). Used by
:class:`~deepbbs_ros.core.localization.MapLocalizer`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.localization_types import _Answer


def threshold(config: Config) -> float:
    """The score an answer needs by itself: the verdict's threshold and ``localization.min_score``."""
    return max(config.registration.verdict_threshold, config.localization.min_score)


def fits(config: Config, score: float) -> bool:
    """The registration's verdict as the map takes it: its fitness against ``registration.verdict_threshold``. The
    map's bars (``localization.min_score``, ``sharp_score``, ``agree_margin``) are calibrated on the fitness, not on
    the registration's calibrated probability, which the map's acceptance does not use yet."""
    from deepbbs_ros.core import verdict

    return verdict.is_valid(score, config.registration.verdict_threshold)


def accepts(config: Config, valid: bool, score: float) -> bool:
    """The registration's verdict and the map's own bar (``localization.min_score``)."""
    return bool(valid) and np.isfinite(score) and score >= config.localization.min_score


def accepts_fit(config: Config, score: float) -> bool:
    """:func:`accepts` with the verdict taken from the fitness (:func:`fits`): how the map judges every answer."""
    return accepts(config, fits(config, score), score)


def sharpness(src: Any, ans: _Answer, config: Config, registration: Any) -> float:
    """Of the scan's verdict points within ``localization.sharp_dist`` of the answer's crop, the share within
    ``registration.verdict_dist`` (0 when none or no crop cloud): a fit that is close wherever the map covers
    the scan, whatever the share the map covers (another carriageway sees another side of the road). Measured once
    per answer (kept in ``ans.sharp``)."""
    if ans.sharp is None:
        ans.sharp = measure_sharpness(src, ans, config, registration)
    return ans.sharp


def measure_sharpness(src: Any, ans: _Answer, config: Config, registration: Any) -> float:
    """:func:`sharpness`, measured anew."""
    tgt = ans.crop.pre.polish_cloud
    if tgt is None or len(src.points) == 0:
        return 0.0
    if getattr(tgt, "pending", None) is not None:
        tgt.complete(threads=registration.gicp_threads())
    T = np.linalg.inv(ans.crop.T_map_place) @ ans.T
    pts = np.asarray(src.points, np.float64) @ T[:3, :3].T + T[:3, 3]
    _, sq = tgt.tree.batch_nearest_neighbor_search(pts, num_threads=1)
    sq = np.asarray(sq, np.float64)
    covered = int(np.sum(sq <= config.localization.sharp_dist ** 2))
    close = int(np.sum(sq <= config.registration.verdict_dist ** 2))
    return close / covered if covered else 0.0


def sharp(src: Any, ans: _Answer, config: Config, registration: Any) -> bool:
    """An answer under min_score accepted all the same (``sharp_score``): valid by the registration's verdict and
    sharp (:func:`sharpness`)."""
    lc = config.localization
    return (lc.sharp_score > 0 and ans.score >= config.registration.verdict_threshold
            and sharpness(src, ans, config, registration) >= lc.sharp_score)


def agreed(src: Any, answers: list[_Answer], best: _Answer, config: Config, registration: Any) -> bool:
    """An answer under min_score, not sharp, accepted all the same (``agree_margin``): valid by the registration's
    verdict, the answers of at least two candidate places within 1 deg / 0.3 m of it, at least ``agree_sharp``
    sharp, and every answer more than ``ambiguity_distance`` away at least ``agree_margin`` lower."""
    from deepbbs_ros.metrics import pair_errors

    lc = config.localization
    if lc.agree_margin <= 0 or not best.score >= config.registration.verdict_threshold:
        return False
    near = [a for a in answers if not a.probe]
    rot, trans = pair_errors(np.stack([a.T for a in near]), np.repeat(best.T[None], len(near), axis=0))
    places = {a.place for a, r, t in zip(near, rot, trans, strict=True) if r <= 1.0 and t <= 0.3}
    if len(places) < 2:
        return False
    far = [a.score for a in answers if np.linalg.norm(a.T[:3, 3] - best.T[:3, 3]) > lc.ambiguity_distance]
    if far and max(far) > best.score - lc.agree_margin:
        return False
    return sharpness(src, best, config, registration) >= lc.agree_sharp


def rivals(src: Any, best: _Answer, pool: list[_Answer], sharp_best: bool, config: Config,
           registration: Any) -> list[_Answer]:
    """The answers of ``pool`` (best first, ``best`` its first) that make ``best`` ambiguous: accepted ones (any
    one when ``sharp_best``: ``best`` is accepted as sharp), within ``ambiguity_margin`` of its score (a probe's:
    ``ambiguity_probe_margin``) and more than ``ambiguity_distance`` away (a probe's: half ``ambiguity_probe``, at
    least 0.5 m); another place's only when it is about as sharp (``ambiguity_sharp_margin``)."""
    lc = config.localization
    out = [a for a in pool[1:] if (a.ok or sharp_best) and a.score >= best.score - (
               lc.ambiguity_probe_margin if a.probe else lc.ambiguity_margin)
           and np.linalg.norm(a.T[:3, 3] - best.T[:3, 3]) > (
               max(0.5, 0.5 * lc.ambiguity_probe) if a.probe else lc.ambiguity_distance)]
    if lc.ambiguity_sharp_margin < 1 and any(not a.probe for a in out):
        # another place ties only when it fits about as closely where the map covers the scan: a look-alike
        # stretch of a highway scores near the right pose but fits looser
        bar = sharpness(src, best, config, registration) - lc.ambiguity_sharp_margin
        out = [a for a in out if a.probe or sharpness(src, a, config, registration) >= bar]
    return out
