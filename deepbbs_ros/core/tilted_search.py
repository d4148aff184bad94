"""The search's second round for a tilted sensor (no ROS): :class:`TiltedSearch`, a mixin of
:class:`~deepbbs_ros.core.place_search.PlaceSearch`.

The place descriptor assumes an upright sensor. A scan whose own ground plane tilts more than the ground fit can tell
from level (a car rolled 14 degrees on a road's edge) sees its low side's road close by only and its heights shifted:
upright, its descriptor ranks look-alike places first. When the upright round accepts no place, such a scan is
described levelled by its ground plane, compared on the descriptor bins it saw only (on the shortlist), and its
candidates start with its tilt. Works on the localizer's map, crops and configuration as ``PlaceSearch`` does.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from deepbbs_ros.core.descriptors import levelling
from deepbbs_ros.core.ground_plane import fit_band
from deepbbs_ros.core.localization_types import _Answer, _rz, answer_rank
from deepbbs_ros.errors import LocalizationError


class TiltedSearch:
    """The levelled round of the global search (module docstring)."""

    def _levelled_round(self, pts: np.ndarray, src: Any, among: np.ndarray | None, centres: np.ndarray,
                        answers: list[_Answer], failed: list, timings: dict[str, float]) -> None:
        """The upright round accepted no place: when the scan is tilted (:meth:`_levelling`), a second round on the scan
        described levelled, compared on the bins it saw (``MapLocalizer.seen``), started with its tilt
        (``PlaceSearch._round``), its best answer tried again on a crop centred at its pose (:meth:`_recentred`);
        ``answers`` and ``failed`` (as ``_round``'s) added to in place. A levelled start within the registration's
        good-start reach of an upright start the round before registered and failed
        (``registration.good_start_max_trans`` m and ``good_start_max_rot_deg`` degrees: how far GICP may move a start
        it is trusted from) is not registered again: GICP alone retries from the upright one (the real cars' scans in
        the benchmarks, tilted 0.6-6.4 degrees by their mounts and roads, rank the same places levelled at the same yaw;
        a narrow field of view compared on the bins it saw ranks other places, or the same at another yaw)."""
        level = self._levelling(src)
        if level is None:
            return
        t = time.perf_counter()
        scan = pts @ level[:3, :3].T
        again = self.rank(self.describe(scan, centres), among, centres, seen=self.seen(scan))
        timings["rank"] = timings.get("rank", 0.0) + (time.perf_counter() - t) * 1e3
        tried = [answers[k].crop.T_map_place @ T_init for k, _, T_init, _ in failed]
        again = [r for r in again if not any(self._within_reach(self._places[r[0]] @ _start(r[2], r[3], level), S)
                                             for S in tried)]
        first = len(answers)
        self._round(src, again, level, answers, failed, timings)
        self._recentred(src, answers[first:], answers, timings)

    def _within_reach(self, A: np.ndarray, B: np.ndarray) -> bool:
        """Two starts (4, 4) within ``registration.good_start_max_trans`` m (horizontally) and
        ``good_start_max_rot_deg`` degrees of each other."""
        rc = self.config.registration
        cos = np.clip((np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        return bool(np.linalg.norm(A[:2, 3] - B[:2, 3]) <= rc.good_start_max_trans
                    and np.degrees(np.arccos(cos)) <= rc.good_start_max_rot_deg)

    def _recentred(self, src: Any, round_answers: list[_Answer], answers: list[_Answer],
                   timings: dict[str, float]) -> None:
        """None of ``round_answers`` accepted, the best fitting by the registration's threshold: GICP from its pose
        on a crop centred there (the place's crop reaches less of what a tilted scan sees), added to ``answers``."""
        best = min(round_answers, key=answer_rank, default=None)
        if best is None or best.ok or not best.score >= self.config.registration.verdict_threshold:
            return
        T_place = np.eye(4)
        T_place[:3, 3] = best.T[:3, 3]
        try:
            crop = self._crop(-1, T_place)
        except LocalizationError:
            return
        t = time.perf_counter()
        alt = self._gicp(src, crop, np.linalg.inv(T_place) @ best.T, best.place)
        timings["gicp"] = timings.get("gicp", 0.0) + (time.perf_counter() - t) * 1e3
        if alt is not None:
            answers.append(alt)

    def _levelling(self, src: Any) -> np.ndarray | None:
        """(4, 4) the rotation that levels the scan by its ground plane (core/descriptors.py ``levelling``, the band
        and radius of the ground fit: core/ground_plane.py), None when upright within the fit's resolution."""
        pc = self.config.preprocess
        R = levelling(getattr(src, "ground_plane", None), fit_band(pc), pc.ground_seed_radius)
        if R is None:
            return None
        T = np.eye(4)
        T[:3, :3] = R
        return T


def _start(yaw: float, centre: np.ndarray, level: np.ndarray | None) -> np.ndarray:
    """(4, 4) a round's start on a place (``PlaceSearch._place_start``'s, less its height): the scan turned by
    ``yaw`` with its point ``centre`` (2,) on the place, levelled by ``level``."""
    T = _rz(yaw)
    T[:2, 3] = -T[:2, :2] @ np.asarray(centre, np.float64)
    return T if level is None else T @ level
