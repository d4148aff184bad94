"""Localization in a prior map over any iterable of scans: every scan through the map tracker,
:class:`LocalizationResults` filled as it goes (see :mod:`deepbbs_ros.replay.runner`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.config import Config
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.replay.loop import keep_on_interrupt, strided


# --------------------------------------------------------------------------------------------------
# localization in a prior map
# --------------------------------------------------------------------------------------------------
@dataclass
class LocalizationRecord:
    """One scan through the map tracker (:class:`~deepbbs_ros.core.tracking.MapTracker`).

    T_map_est: (4, 4) float64 the tracker's pose of the scan in the map frame (NaN when it gave none);
    published only when ``valid``. T_map_gt: (4, 4) the recording's ground truth (taken to be in the map frame),
    or None. rot_err_deg / trans_err_m: of ``T_map_est`` against it (NaN without either). time_ms: the
    tracker's wall time for the scan (``step``), ms."""

    index: int
    stamp_ns: int
    event: str
    valid: bool
    score: float
    mode: str
    path: str
    reason: str
    candidates: int
    time_ms: float
    T_map_est: np.ndarray
    T_map_gt: np.ndarray | None
    rot_err_deg: float
    trans_err_m: float
    timings_ms: dict[str, float] = field(default_factory=dict)


@dataclass
class LocalizationResults:
    records: list[LocalizationRecord] = field(default_factory=list)
    frame_id: str = ""
    frames_read: int = 0
    complete: bool = True
    errors: list[str] = field(default_factory=list)
    recoveries: int = 0
    setup_ms: float = float("nan")  # building the localizer (places, descriptors)
    map_points: int = 0
    places: np.ndarray | None = None  # (P, 4, 4) the localizer's candidate places (plots)
    map_xyz: np.ndarray | None = None  # (N, 3) the map (plots, results bag)
    warnings: list[str] = field(default_factory=list)  # e.g. a map trajectory that does not fit the map

    @property
    def frames(self) -> int:
        return len(self.records)

    @property
    def has_ground_truth(self) -> bool:
        return bool(self.records) and all(r.T_map_gt is not None for r in self.records)


def run_localization(
    scans: Iterable[Scan],
    tracker: Any,
    config: Config,
    *,
    max_frames: int | None = None,
    progress: Callable[[int], None] | None = None,
    results: LocalizationResults | None = None,
) -> LocalizationResults:
    """Every ``config.eval.odom_stride``-th scan through ``tracker.step(points, stamp_ns, times)`` (a
    :class:`~deepbbs_ros.core.tracking.MapTracker`: no initial pose, it searches the map first), one
    :class:`LocalizationRecord` per scan. A :class:`~deepbbs_ros.errors.DeepBBSError` on a scan (too few points)
    is that scan's "error" event (no pose) and the run goes on. KeyboardInterrupt stops the loop with
    ``complete=False``, the scans so far kept."""
    ev = config.eval
    res = results or LocalizationResults()
    nan4 = np.full((4, 4), np.nan)
    with keep_on_interrupt(res):
        for _, scan in strided(scans, res, ev.odom_stride, progress):
            if max_frames is not None and len(res.records) >= max_frames:
                break
            res.frame_id = res.frame_id or scan.frame_id
            t0 = time.perf_counter()
            try:
                out = tracker.step(scan.points, scan.stamp_ns, scan.point_times())
            except DeepBBSError as err:
                out = None
                reason = str(err)
            ms = (time.perf_counter() - t0) * 1e3
            gt = None if scan.T_world_lidar is None else scan.T_world_lidar.copy()
            if out is None:
                rec = LocalizationRecord(scan.index, scan.stamp_ns, "error", False, float("nan"), "", "", reason, 0, ms,
                                         nan4.copy(), gt, float("nan"), float("nan"))
            else:
                T = np.asarray(out.T_map_scan, dtype=np.float64)
                if not out.valid or not np.isfinite(T).all():
                    T = nan4.copy()
                rot, tr = (metrics.pair_errors(T, gt) if gt is not None and np.isfinite(T).all()
                           else (float("nan"), float("nan")))
                event = out.event or ("found" if out.valid else "searching")
                rec = LocalizationRecord(
                    scan.index, scan.stamp_ns, event, bool(out.valid), float(out.score), out.mode,
                    getattr(out, "path", ""), out.reason, int(getattr(out, "candidates", 0)), ms, T, gt, float(rot),
                    float(tr), dict(getattr(out, "timings_ms", {}) or {}))
            res.records.append(rec)
            res.recoveries = int(getattr(tracker, "recoveries", 0))
    return res
