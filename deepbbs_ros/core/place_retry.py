"""The global search's second tries (no ROS): :class:`PlaceRetries`, the part of
:class:`~deepbbs_ros.core.place_search.PlaceSearch` that, when no place is accepted, tries again (``_retry``: GICP alone
from the failed starts, the opposite yaw, the registration's own search, starts slid along the road) and the GICP
answers it and the search share (``_gicp``, ``_better_gicp``, ``_refined``). A mixin: it works on the localizer's
crops, registration and configuration, and on the search's ``_answer`` / ``_deep``.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core.localization_types import _Answer, _Crop, _heading, _rz, answer_rank
from deepbbs_ros.core.polish import polish


class PlaceRetries:
    """The retries and GICP answers of :class:`~deepbbs_ros.core.place_search.PlaceSearch` (module docstring)."""

    def _retry(self, src: Any, answers: list[_Answer], failed: list[tuple[int, int, np.ndarray, float]],
               timings: dict[str, float], quick: bool = False) -> None:
        """No place accepted (``answers``, replaced and added to in place): the ``failed`` starts (index in
        ``answers``, rank, T_place_scan, yaw) again with GICP alone (the network's pass went astray); still none
        accepted: DeepBBS++ from the opposite yaw on the best ``flip_starts`` places (a street looks alike both ways);
        still none: the best once more with the registration's global search (the right place with a poor pose?); still
        none: GICP alone from far_probe m ahead of and behind the best pose and the best-ranked place's (:meth:`_slid`:
        a pose slid along the road). Not when a place was accepted (on the benchmark's queries these retries changed
        no outcome there, at 0.4 s a query). ``quick``: GICP alone only (:meth:`_global`: the best first answer's
        probability under ``localization.retry_probability``, its descriptor distance at least ``retry_descriptor`` or
        the probability under ``retry_floor``)."""
        lc = self.config.localization
        search = lc.candidate_search != "off"
        for k, _, T_init, _ in failed:
            answers[k] = self._better_gicp(src, answers[k].crop, T_init, answers[k].place, answers[k], timings)
        if quick:
            return
        if not any(a.ok for a in answers):
            for k, rank_i, T_init, yaw in failed:
                if not answers[k].ok and rank_i < lc.flip_starts:
                    answers[k] = self._flipped(src, answers[k], T_init, yaw, timings, search)
        best = min(answers, key=answer_rank)
        if (not best.ok and not search and self._searchable
                and best.score >= self.config.registration.verdict_threshold):
            T_init = np.linalg.inv(best.crop.T_map_place) @ best.T
            answers.append(self._deep(src, best.crop, T_init, best.place, timings))
        best = min(answers, key=answer_rank)
        if not any(a.ok for a in answers) and lc.far_probe > 0:
            # the best fit, and the best-ranked place (the right place whose pose slid away from it scores low)
            for ans in [best] if answers[0] is best else [best, answers[0]]:
                answers.extend(self._slid(src, ans, timings))

    def _slid(self, src: Any, best: _Answer, timings: dict[str, float]) -> list[_Answer]:
        """GICP alone from ``far_probe`` m ahead of and behind the best answer's pose, along its heading: -> their
        answers (judged by the map verdict as every answer). The right place with its pose slid along a highway
        (2.7 m, score 0.33) comes back to the true pose from the start 3.5 m back."""
        T = np.linalg.inv(best.crop.T_map_place) @ best.T
        head = _heading(T)
        out = []
        t = time.perf_counter()
        for side in (1.0, -1.0):
            S = T.copy()
            S[:2, 3] += side * self.config.localization.far_probe * head
            alt = self._gicp(src, best.crop, S, best.place)
            if alt is not None:
                out.append(alt)
        timings["gicp"] = timings.get("gicp", 0.0) + (time.perf_counter() - t) * 1e3
        return out

    def _refined(self, src: Any, answers: list[_Answer], timings: dict[str, float]) -> _Answer:
        """The best of ``answers`` (``answer_rank``); when it is not accepted but fits by the registration's threshold
        (``registration.verdict_threshold``), refined (:meth:`_refine`) and judged again, in place, when that fits
        better (a highway scan taken the other way: 0.44 m along the road; refined 0.01 m)."""
        from deepbbs_ros.core import verdict

        rc = self.config.registration
        ans = min(answers, key=answer_rank)
        if ans.ok or ans.refined or not ans.score >= rc.verdict_threshold:
            return ans
        ans.refined = True
        T = self._refine(src, ans.crop, ans.T, timings)
        if T is ans.T:  # not refined (no GICP clouds, not converged, moved too far)
            return ans
        score = verdict.fitness(src.points, ans.crop.pre.polish_cloud.tree, np.linalg.inv(ans.crop.T_map_place) @ T,
                                rc.verdict_dist)
        if score >= ans.score:
            new = self._answer(score, T, ans.place, ans.crop, src)
            ans.T, ans.score, ans.prob, ans.ok = T, score, new.prob, new.ok
        return ans

    def _better_gicp(self, src: Any, crop: _Crop, T_init: np.ndarray, place: int, ans: _Answer,
                     timings: dict[str, float]) -> _Answer:
        """GICP alone from T_init (:meth:`_gicp`) beside the network's ``ans``: the better of the two."""
        t = time.perf_counter()
        alt = self._gicp(src, crop, T_init, place)
        timings["gicp"] = timings.get("gicp", 0.0) + (time.perf_counter() - t) * 1e3
        return alt if alt is not None and alt.score > ans.score and (alt.ok or not ans.ok) else ans

    def _flipped(self, src: Any, ans: _Answer, T_init: np.ndarray, yaw: float, timings: dict[str, float],
                 search: bool) -> _Answer:
        """DeepBBS++ from T_init turned to the opposite yaw beside ``ans``: the better of the two."""
        T_flip = T_init.copy()
        T_flip[:3, :3] = _rz(yaw + np.pi)[:3, :3]
        T_flip[:2, 3] = -T_init[:2, 3]  # the same point of the scan on the place
        flip = self._deep(src, ans.crop, T_flip, ans.place, timings, yaw_search=search)
        return flip if flip.score > ans.score else ans

    @property
    def _searchable(self) -> bool:
        """The registration has a global search of its own to fall back on."""
        rc = getattr(getattr(self.registration, "config", None), "registration", None)
        return rc is not None and rc.global_search != "off"

    def _gicp(self, src: Any, crop: _Crop, T_place_scan: np.ndarray, place: int) -> _Answer | None:
        """GICP of the scan's precision-stage cloud on the crop's from T_place_scan, with the verdict's score, judged
        by the map verdict (GICP alone from a rough start settles on look-alike stretches with a passing fitness: a
        highway 27 m along, 0.65; the probability and the rivals' check decide)."""
        from deepbbs_ros.core import verdict

        rc = self.config.registration
        if src.polish_cloud is None or crop.pre.polish_cloud is None or rc.polish == "none":
            return None
        for pc in (src.polish_cloud, crop.pre.polish_cloud):
            if getattr(pc, "pending", None) is not None:
                pc.complete(threads=self.registration.gicp_threads())
        pol = polish(src.polish_cloud, crop.pre.polish_cloud, T_place_scan, rc, check=self._check_at(src, crop))
        if not pol.applied:
            return None
        score = verdict.fitness(src.points, crop.pre.polish_cloud.tree, pol.T_target_source, rc.verdict_dist)
        return self._answer(score, crop.T_map_place @ pol.T_target_source, place, crop, src, gicp=True)
