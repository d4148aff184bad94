"""The global search over a map's candidate places (no ROS): :class:`PlaceSearch`, the part of
:class:`~deepbbs_ros.core.localization.MapLocalizer` that registers a scan on the places its descriptor ranks best
and chooses among the answers.

``_global`` reads top-down: describe the scan and rank the places (``MapLocalizer.describe`` / ``rank``); DeepBBS++
on each candidate's crop from the descriptor's yaw (GICP alone beside an answer under ``confident_score``); when
none is accepted, the retries (``_retry``, core/place_retry.py: GICP alone, the opposite yaw, the registration's own
search, starts slid along the road); the best answer, probed around for a better optimum or a slide (``_probe``,
core/place_probe.py); the acceptance rules (core/acceptance.py) decide: a pose, or no pose and why. A mixin: it works
on the localizer's map, crops, registration and configuration (``self.config``, ``self.registration``,
``self._crop``, ``self.grid``, ...).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core import acceptance
from deepbbs_ros.core.localization_types import LocalizationResult, _Answer, _Crop, _crop_cloud, answer_rank
from deepbbs_ros.core.place_probe import MIN_PROBE_POINTS, PlaceProbes  # noqa: F401
from deepbbs_ros.core.place_retry import PlaceRetries
from deepbbs_ros.core.tilted_search import TiltedSearch, _start


class PlaceSearch(PlaceRetries, PlaceProbes, TiltedSearch):
    """The global search of :class:`~deepbbs_ros.core.localization.MapLocalizer` (module docstring)."""

    def _answer(self, score: float, T_map_scan: np.ndarray, place: int, crop: _Crop, src: Any,
                **kw: bool) -> _Answer:
        """An answer at ``T_map_scan`` on ``crop`` with the registration's ``score``, judged by the map verdict
        (core/acceptance.py); ``kw``: ``probe``, ``gicp``."""
        prob = acceptance.probability(src, crop, T_map_scan, self.config)
        return _Answer(float(score), acceptance.accepts(self.config, prob), T_map_scan, place, crop, prob=prob, **kw)

    def _deep(self, src: Any, crop: _Crop, T_place_scan: np.ndarray, place: int, timings: dict[str, float],
              yaw_search: bool = True) -> _Answer:
        """:meth:`_register` as a global search's answer (map frame, the map's bar), timed into ``register``."""
        t = time.perf_counter()
        reg = self._register(src, crop, T_place_scan, yaw_search=yaw_search, judged=True)
        timings["register"] = timings.get("register", 0.0) + (time.perf_counter() - t) * 1e3
        return self._answer(float(reg.score), crop.T_map_place @ reg.T_target_source, place, crop, src)

    def _global(self, pts: np.ndarray, src: Any, among: np.ndarray | None,
                timings: dict[str, float]) -> LocalizationResult:
        lc = self.config.localization
        t = time.perf_counter()
        centres = self.description_centres
        desc = self.describe(pts, centres)
        timings["describe"] = timings.get("describe", 0.0) + (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        ranked = self.rank(desc, among, centres)
        timings["rank"] = timings.get("rank", 0.0) + (time.perf_counter() - t) * 1e3
        answers: list[_Answer] = []
        failed: list[tuple[int, int, np.ndarray, float]] = []  # (index in answers, rank, T_init, yaw): failed starts
        self._round(src, ranked, None, answers, failed, timings)
        if not any(a.ok for a in answers):
            self._levelled_round(pts, src, among, centres, answers, failed, timings)  # core/tilted_search.py
        n = len(answers)
        if not answers:
            return LocalizationResult(np.eye(4), False, float("nan"), "global", "no candidate place in reach")
        outside = self._outside(src, answers, ranked, timings)
        if not any(a.ok for a in answers):
            # no place accepted: the failed starts again; only GICP alone (cheap: on a wrong place its check stops it
            # early) when the best answer is far below the bar and no place looks like the scan either (outside the
            # map?)
            self._retry(src, answers, failed, timings, quick=outside)
        answers.sort(key=answer_rank)
        best = self._refined(src, answers, timings)
        if not best.ok:
            why = (f"best probability {best.prob:.2f} < {self._threshold:.2f}, score {best.score:.2f}"
                   + (": scan outside the map?" if outside else ""))
            return LocalizationResult(best.T, False, best.score, "global", f"no candidate place passed the verdict "
                                      f"({why})", candidates=n, path="deepbbs", place=best.place,
                                      probability=best.prob)
        t = time.perf_counter()
        probes = self._probe(src, best)
        timings["probe"] = (time.perf_counter() - t) * 1e3
        pool = sorted(answers + probes, key=answer_rank)
        best = pool[0]  # a probe may land on a better pose than the registration's (a local optimum nearby)
        rivals = acceptance.rivals(best, pool, self.config)
        alternatives = [(float(a.T[0, 3]), float(a.T[1, 3]), a.score) for a in answers if a.ok and a is not best
                        and np.linalg.norm(a.T[:3, 3] - best.T[:3, 3]) > lc.ambiguity_distance]
        if rivals:
            far = max(float(np.linalg.norm(a.T[:3, 3] - best.T[:3, 3])) for a in rivals)
            what = "the pose slides along a stretch without features" if all(a.probe for a in rivals) else \
                f"{len(rivals) + 1} places"
            return LocalizationResult(best.T, False, best.score, "global",
                                      f"ambiguous: {what}, {far:.1f} m apart, score {best.score:.2f} / "
                                      f"{rivals[0].score:.2f}", candidates=n, path="deepbbs", place=best.place,
                                      alternatives=alternatives, probability=best.prob)
        # the probes looked for other minima around it (a better one is the answer now, one as good a rival); without
        # probes, the second-minimum check does (core/acceptance.py)
        t = time.perf_counter()
        second = acceptance.second_minimum(src, best.crop, best.T, self.config) if not probes else None
        timings["second_minimum"] = (time.perf_counter() - t) * 1e3
        if second is not None and second.ambiguous:
            return LocalizationResult(best.T, False, best.score, "global", "ambiguous: another minimum as good "
                                      f"{second.offset:.1f} tolerances along the direction the fit leaves free",
                                      candidates=n, path="deepbbs", place=best.place, probability=best.prob)
        T = self._refine(src, best.crop, best.T, timings)
        return LocalizationResult(T, True, best.score, "global", "", candidates=n, path="deepbbs",
                                  crop=_crop_cloud(best.crop), place=best.place, alternatives=alternatives,
                                  covariance=self._covariance(src, best.crop, T, timings),
                                  probability=best.prob)

    def _round(self, src: Any, ranked: list, level: np.ndarray | None, answers: list[_Answer],
               failed: list[tuple[int, int, np.ndarray, float]], timings: dict[str, float]) -> None:
        """One round of the search: DeepBBS++ on each ``ranked`` place from the descriptor's yaw (turned by
        ``level``, (4, 4) or None, the scan's levelling) until an accepted answer ends it; ``answers`` and
        ``failed`` (index in answers, rank, T_init, yaw) are added to in place."""
        lc = self.config.localization
        h_scan = self._sensor_height(src)
        accepted_dist = None  # descriptor distance of the first accepted candidate
        search = lc.candidate_search != "off"
        sure = self.config.registration.verdict_sure
        for rank_i, (place, dist, yaw, centre) in enumerate(ranked):
            if accepted_dist is not None and dist > accepted_dist + lc.descriptor_margin:
                break  # the rest look less alike than the margin: not a rival
            t = time.perf_counter()
            crop = self._crop(place)
            timings["crop"] = timings.get("crop", 0.0) + (time.perf_counter() - t) * 1e3
            T_init = self._place_start(crop, yaw, centre, level, h_scan)
            ans = self._deep(src, crop, T_init, place, timings, yaw_search=search)
            if ans.ok and ans.score < lc.confident_score:
                # the network's pass settled on a poor optimum (a lane off)? GICP alone from the descriptor's start
                # (good to ~2 m), the better of the two kept
                ans = self._better_gicp(src, crop, T_init, place, ans, timings)
            if not ans.ok:
                failed.append((len(answers), rank_i, T_init, yaw))
            answers.append(ans)
            if ans.ok and accepted_dist is None and (ans.score >= lc.confident_score or ans.prob >= sure):
                accepted_dist = dist  # a fit this close, or a verdict this sure: only look-alike places are rivals

    def _place_start(self, crop: _Crop, yaw: float, centre: np.ndarray, level: np.ndarray | None,
                     h_scan: float | None) -> np.ndarray:
        """(4, 4) T_place_scan, the descriptor's start on ``crop``'s place: the scan turned by ``yaw`` with its point
        ``centre`` (2,) on the place, levelled by ``level`` (4, 4) or None, at its own height above the ground
        ``h_scan`` (m; :meth:`_sensor_height`, None: unknown)."""
        T_init = _start(yaw, centre, level)
        if h_scan is not None:  # the crop's origin is the place's sensor: the scan's own height above the ground
            g = self.grid.ground_at(crop.T_map_place[None, :2, 3], np.nan)[0]
            if np.isfinite(g):
                T_init[2, 3] = g + h_scan - crop.T_map_place[2, 3]
        return T_init

    def _outside(self, src: Any, answers: list[_Answer], ranked: list, timings: dict[str, float]) -> bool:
        """The first round's answers say the scan is not in the map (then the quick retry only): the best one
        (refined, :meth:`_refined`) under ``localization.retry_probability``, and the best-ranked place's descriptor
        distance at least ``retry_descriptor`` (no place looks like the scan) or that probability under
        ``retry_floor``. Not asked before the round's end: after its first candidate, scans a later candidate places
        look the same (highway: descriptor 0.25, first answer 0.000-0.001; the real map: 0.42, 0.000) as scans from
        elsewhere (0.33-0.52, under 0.05)."""
        lc = self.config.localization
        top = self._refined(src, answers, timings)
        return top.prob < lc.retry_probability and (ranked[0][1] >= lc.retry_descriptor or top.prob < lc.retry_floor)
