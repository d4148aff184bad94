"""Tracking from a guess in a prior map (no ROS): :class:`GuessTracking`, the part of
:class:`~deepbbs_ros.core.localization.MapLocalizer` that registers a scan from a predicted pose.

GICP of the scan on the crop of the place nearest the guess (the crop tracked last while it still serves; off the
places, a crop at the guess), from the guess, with register()'s good-start verdict; other starts (the tracker's last
pose at rest) are ranked with it by how much of the scan lies on the map there (the verdict's fitness, a k-d tree query
of a few hundred points), GICP from each in that order until one is accepted: a sensor that stopped or turned back is
tracked by GICP from the start nearest it, not by DeepBBS++; DeepBBS++ from the best-fitting start when every GICP
is rejected, and a search among the places within ``localization.track_search_radius`` when that is too, unless the
score fell far below the recent scans' (``track_drop``: a kidnap, the global search decides). A mixin: it works on
the localizer's places, crops, registration and configuration. :class:`~deepbbs_ros.core.tracking.MapTracker` drives it.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core import acceptance, map_verdict
from deepbbs_ros.core.localization_types import LocalizationResult, _Answer, _Crop, _crop_cloud


class GuessTracking:
    """Tracking from a guess for :class:`~deepbbs_ros.core.localization.MapLocalizer` (module docstring)."""

    def _track(self, pts: np.ndarray, src: Any, guess: np.ndarray, timings: dict[str, float],
               starts: Any = ()) -> LocalizationResult:
        lc = self.config.localization
        t = time.perf_counter()
        xy = self._places[:, :2, 3]
        d = np.linalg.norm(xy - guess[:2, 3], axis=1)
        near = int(np.argmin(d))
        reach = max(lc.place_spacing, 0.25 * self.crop_radius)  # a crop serves while the sensor is this close to it
        if self._track_place >= 0 and d[self._track_place] <= reach:
            near = self._track_place  # the same crop as the last scan: no new preprocessing, the network's memo
        if d[near] <= reach:
            crop = self._crop(near)
            self._track_place = near
        else:  # off the places: a crop at the guess (gravity-aligned), kept while the sensor stays near it
            near, crop = -1, self._guess_crop
            if crop is None or np.linalg.norm(crop.T_map_place[:2, 3] - guess[:2, 3]) > reach:
                T = np.eye(4)
                T[:3, 3] = guess[:3, 3]
                crop = self._guess_crop = self._crop(-1, T)
        timings["crop"] = (time.perf_counter() - t) * 1e3
        C_inv = np.linalg.inv(crop.T_map_place)
        T_guess = C_inv @ guess  # T_place_scan
        t = time.perf_counter()
        # GICP from the guess (the GICP anchor's work) and the verdict on a spread subset of the scan's voxels, as
        # register(..., good_start=True) does, but here: its score decides whether the scan is worth a retry; the
        # other starts ranked with it by their fitness, GICP from each in turn until one is accepted
        ans, at_guess, T_guess = self._track_gicp(src, crop, [T_guess, *(C_inv @ s for s in starts)], near)
        timings["gicp"] = (time.perf_counter() - t) * 1e3
        guess = crop.T_map_place @ T_guess  # the best-fitting start: the DeepBBS++ path's
        score, T_map_scan, path = at_guess, guess, "gicp"
        if ans is not None:
            score, T_map_scan = ans.score, ans.T
            if ans.ok:
                self._track_scores.append(ans.score)
                res = self._tracked(src, crop, ans.T, ans.score, path, near, timings)
                res.probability = ans.prob
                return res
        recent = float(np.median(self._track_scores)) if len(self._track_scores) >= 2 else float("nan")
        if np.isfinite(score) and score < lc.track_drop * recent:  # nan-safe: no recent scores, no shortcut
            # far below the recent scans' scores: not a poor fit but another place (a kidnap, the map's end); the
            # DeepBBS++ retry and the local search would cost seconds to say so: the global search decides
            return LocalizationResult(T_map_scan, False, score, "tracking",
                                      f"rejected from the guess: score {score:.2f} far below the recent "
                                      f"{recent:.2f} (no local search)", candidates=1, path=path, place=near)
        t = time.perf_counter()
        # DeepBBS++ from the guess (its GICP-first path was ours); a rejection goes to the local search below, not to
        # other yaws
        reg = self._register(src, crop, T_guess, yaw_search=False)
        timings["register"] = (time.perf_counter() - t) * 1e3
        path = getattr(reg, "path", "") or "deepbbs"
        if not (reg.score <= score):  # nan-safe: the better of the two
            score, T_map_scan = float(reg.score), crop.T_map_place @ reg.T_target_source
        if self._accepts_at(src, crop, crop.T_map_place @ reg.T_target_source):
            return self._tracked(src, crop, crop.T_map_place @ reg.T_target_source, float(reg.score), path, near,
                                 timings)
        if lc.track_search_radius > 0:  # a local search among the places around the guess
            among = np.flatnonzero(d <= lc.track_search_radius)
            if len(among):
                res = self._global(pts, src, among, timings)
                res.mode, res.path = "tracking", "search"
                if res.valid:
                    return res
                res.reason = f"rejected from the guess (score {score:.2f}); local search: {res.reason}"
                return res
        return LocalizationResult(T_map_scan, False, score, "tracking", f"rejected from the guess (score {score:.2f})",
                                  candidates=1, path=path, place=near)

    def _tracked(self, src: Any, crop: _Crop, T_map_scan: np.ndarray, score: float, path: str, place: int,
                 timings: dict[str, float]) -> LocalizationResult:
        if self.config.localization.refine_tracking:
            T_map_scan = self._refine(src, crop, T_map_scan, timings)
        return LocalizationResult(T_map_scan, True, score, "tracking", "", candidates=1, path=path,
                                  crop=_crop_cloud(crop), place=place,
                                  covariance=self._covariance(src, crop, T_map_scan, timings))

    def _track_gicp(self, src: Any, crop: _Crop, starts: list[np.ndarray],
                    place: int) -> tuple[_Answer | None, float, np.ndarray]:
        """Tracking's GICP from the starts T_place_scan (4, 4) (the prediction first) as register()'s good start runs
        it (GICP's own settings, ``registration.polish_*``, taken wherever the verdict accepts it: core/good_start.py
        from_start) and its verdict: the share of a spread subset of the scan's GICP voxels (``good_start_points``) on
        the crop, judged by the map verdict (core/map_verdict.py) as every answer in a map (the registration's
        good-start probability is calibrated on scan-to-scan pairs: on a map crop it ran low for right poses) and its
        second-minimum check (core/acceptance.py). With
        more than one start, they are tried in the order of their fitness (the share of those voxels on the crop at
        the start itself; a tie keeps the prediction first) until one is accepted.
        Only the GICP clouds: the scan's lazy sampling (ground removal, FPS) is not run. -> (the accepted answer, else
        the best-scoring one, or None when GICP applied from no start; the fitness at the best start when GICP did not
        apply, else nan; the best-fitting start)."""
        from deepbbs_ros.core import verdict
        from deepbbs_ros.core.good_start import from_start, good_start_points

        rc = self.config.registration
        if src.polish_cloud is None or crop.pre.polish_cloud is None or rc.polish == "none":
            return None, float("nan"), starts[0]
        th = self.registration.gicp_threads()
        spc, tpc = src.polish_cloud.complete(threads=th), crop.pre.polish_cloud.complete(threads=th)
        pts = good_start_points(spc, rc)
        fits = [verdict.fitness(pts, tpc.tree, T, rc.verdict_dist) for T in starts] if len(starts) > 1 else [np.nan]
        order = sorted(range(len(starts)), key=lambda i: -fits[i])  # stable: the prediction first on a tie
        best: _Answer | None = None
        for i in order:
            pol = from_start(spc, tpc, starts[i], rc)  # as register()'s good start
            if not pol.applied:  # GICP did not converge
                continue
            T = pol.T_target_source
            score = verdict.fitness(pts, tpc.tree, T, rc.verdict_dist)
            prob = map_verdict.probability(map_verdict.features(pts, T, tpc, rc.verdict_dist))
            T_map = crop.T_map_place @ T  # accepted: no other minimum as good along a direction the fit leaves free
            ans = _Answer(score, acceptance.accepts_pose(src, crop, T_map, self.config, prob), T_map, place, crop,
                          prob=prob)
            if ans.ok:
                return ans, float("nan"), starts[i]
            if best is None or ans.score > best.score:
                best = ans
        T0 = starts[order[0]]
        if best is not None:
            return best, float("nan"), T0
        # no GICP applied: how well does the best start itself fit?
        at = fits[order[0]] if np.isfinite(fits[order[0]]) else verdict.fitness(pts, tpc.tree, T0, rc.verdict_dist)
        return None, at, T0
