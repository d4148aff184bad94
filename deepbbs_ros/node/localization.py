"""``node.target_mode: localization``: the live node's pose in a prior map (no ROS import).

The map comes from ``localization.map_path`` (a ``.pcd`` / ``.ply`` file in the map frame, with the trajectory
it was built from beside it when there is one, :func:`load_map_file`) or from the latched map topic
(``target_cloud``, as ``node.target_mode: latched``). :class:`NodeLocalization` owns the
:class:`~deepbbs_ros.core.tracking.MapTracker` over it and runs one :meth:`~NodeLocalization.step` per scan on
the registration worker thread: no initial pose (the whole map is searched), then tracking from the
constant-velocity prediction; the tracker's verdict decides, and only a valid pose is handed on to be published.

State changes are one log line each (:attr:`LocalizedScan.line`): the first pose ("found"), the pose lost (the
tracker's ``localization.lost_after`` rejected scans in a row, or an implausible motion: a kidnap, a drive out of
the map), found again ("relocalized"); a long search says so at most every ``node.error_log_period`` s.
:meth:`~NodeLocalization.relocalize` (the node's ``~/relocalize``) forgets the pose: the next scan searches the
whole map. :meth:`~NodeLocalization.diagnostics` gives the /diagnostics values (state, placed, rejected,
recoveries, last reason, time to first pose).

Threads: :meth:`step` runs on the worker thread only; :meth:`build` (the map input's thread: the map's places and
descriptors are built there, off the worker) and :meth:`relocalize` (the executor thread) only leave a request
that the next :meth:`step` applies, so neither waits for a registration. With ``node.map_prefetch`` a thread of its
own prepares the map crop of the place the tracked pose will reach in :data:`PREFETCH_AHEAD_S` s
(``MapLocalizer.prefetch``), so that the scan that gets there does not wait for it.

A search slower than the scan period does not lose what it finds: the scans that arrived meanwhile are tracked once it
places its scan (node/localization_bridge.py). Its other parts: the map (node/map_data.py), the requests of other
threads (node/localization_requests.py), the counters and state lines (node/localization_account.py), the
/diagnostics values (node/localization_diagnostics.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from deepbbs_ros.errors import DeepBBSError
from deepbbs_ros.node.inputs import BadInput, Cloud
from deepbbs_ros.node.localization_account import LocalizationAccount
from deepbbs_ros.node.localization_bridge import SearchBridge
from deepbbs_ros.node.localization_diagnostics import LocalizationDiagnostics
from deepbbs_ros.node.localization_requests import LocalizationRequests
from deepbbs_ros.node.map_data import MapData
from deepbbs_ros.node.pipeline import Registered

#: the tracker's states, as /diagnostics shows them
STATES = ("searching", "tracking", "lost")
PREFETCH_AHEAD_S = 1.0  # s; node.map_prefetch: the crop of the place the predicted pose reaches this far ahead


@dataclass
class LocalizedScan:
    """One scan through the tracker.

    Attributes:
        result: the tracker's :class:`~deepbbs_ros.core.localization.LocalizationResult` (``.valid``: publish).
        registered: ``T`` = ``T_map_scan`` and the result, in the shape the outputs take.
        crop: (M, 3) map points the answer was registered on (map frame), or None.
        frame_id: the map frame.
        line: a state change to log (found, lost, relocalized, still searching), else None.
    """

    result: Any
    registered: Registered
    crop: np.ndarray | None
    frame_id: str
    line: str | None = None


class NodeLocalization(LocalizationRequests, LocalizationAccount, SearchBridge, LocalizationDiagnostics):
    """The tracker of ``node.target_mode: localization`` and its counters (module docstring).

    Args:
        config: the node's config (``localization`` section; ``node.error_log_period`` for the search reminder).
        registration: the node's DeepBBS++ (``DeepBBSRegistration``, in this process) shared by the localizer.
    """

    def __init__(self, config: Any, registration: Any) -> None:
        from deepbbs_ros.node.worker import LatestSlotWorker

        self.config = config
        self.registration = registration
        self._lock = threading.Lock()
        self.prefetched = 0  # map crops prepared ahead of the tracked pose
        self.prepared = 0  # scans whose GICP cloud was prepared on arrival (input thread), not on the worker
        self._prefetch = None
        if config.node.map_prefetch:
            self._prefetch = LatestSlotWorker(self._prefetch_crop, name="deepbbs-loc-prefetch")
        self._pending_map: MapData | None = None
        self._pending_localizer: Any = None
        self._relocalize = False
        self._hint: tuple[np.ndarray, np.ndarray] | None = None  # hint(): T_map_base, covariance, for the next step
        #: cloud frame -> T_base_sensor (4, 4): a hint is the base's pose, the tracker's the sensor's (set by the node)
        self.extrinsic = lambda frame: np.eye(4)
        self.map: MapData | None = None
        self.tracker: Any = None
        self.localizer: Any = None
        self.map_build_s = float("nan")
        self.map_warning = ""
        # counters (read by diagnostics() from the executor thread)
        self.placed = 0  # scans with a valid pose (published)
        self.rejected = 0  # scans the verdict (or the tracker) rejected: counted, never published
        self.events: dict[str, int] = {}
        self.last_reason = ""
        self.last_event = ""
        self.last_score = float("nan")
        self.last_path = ""
        self.time_to_first_pose_s = float("nan")  # the last search: first scan received -> pose published
        self.first_pose_s = float("nan")  # since the node started (or the map arrived): first pose
        self._search_t0: float | None = None  # perf_counter of the first scan of the running search
        self._search_scans = 0
        self._last_search_log = 0.0
        self._init_bridge(config.localization.bridge_scans)
        self.skipped = 0  # scans the worker got after the bridge had answered them (not registered twice)
        #: test hooks, called on the worker thread before a scan's registration: ``search_gate`` before a search (a scan
        #: with no pose to track from), ``track_gate`` before a tracked scan, so that a test can make a search outlast
        #: the scan period on a tiny map, or tracking slower than the stream, counted in scans; None in use
        self.search_gate: Callable[[], None] | None = None
        self.track_gate: Callable[[], None] | None = None

    # -- one scan ----------------------------------------------------------------------------------------------
    def prepare(self, cloud: Cloud) -> None:
        """On the scan's input thread, on arrival (as the other modes' inputs preprocess): its GICP cloud
        (``MapLocalizer.prepare``, deskewed with the motion the tracker knows now) into ``cloud.pp``, so that
        :meth:`step` only registers it. A scan the localizer refuses is left as it is (:meth:`step` says why)."""
        from deepbbs_ros.core.localization import PreparedScan

        localizer, tracker = self.localizer, self.tracker
        if localizer is None or tracker is None or not hasattr(localizer, "prepare"):
            return
        with self._lock:
            if self._pending_localizer is not None or self._relocalize or self._hint is not None:
                return  # a new map, a reset or a hint waits for step(): prepared there
        motion = tracker.motion() if cloud.times is not None and hasattr(tracker, "motion") else None
        t0 = time.perf_counter()
        try:
            pre = localizer.prepare(cloud.xyz, cloud.times, cloud.stamp_ns, motion)
        except DeepBBSError:
            return
        if isinstance(pre, PreparedScan):
            cloud.pp = (localizer, pre)
            cloud.timings_ms["preprocess"] = (time.perf_counter() - t0) * 1e3

    @property
    def searching(self) -> bool:
        """A map and no pose: the next scan searches."""
        tracker = self.tracker
        return tracker is not None and tracker.state != "tracking"

    def step(self, cloud: Cloud) -> LocalizedScan | None:
        """``MapTracker.step`` on one scan (raw points, per-point times, stamp), on the worker thread; None for a scan
        :meth:`bridge` answered already (counted in :attr:`skipped`).

        Raises:
            BadInput: ``no_target`` before a map, ``localization_failed`` for a scan the localizer refuses
                (too few points; the tracker's state is unchanged).
        """
        from deepbbs_ros.errors import LocalizationError

        if not self._bridging:
            self._bridge_pending = False  # a found pose that no bridge() followed: keep arrivals no longer
        self._take_requests(cloud)
        tracker = self.tracker
        if tracker is None:
            raise BadInput("no_target", "no map yet (localization.map_path is empty and nothing arrived on the map "
                                        "topic, latched: transient_local, reliable)")
        state_before = tracker.state
        if self.answered(cloud.stamp_ns):
            self.skipped += 1
            return None
        if state_before != "tracking" and self._search_t0 is None:
            self._search_t0, self._search_scans = cloud.t_recv, 0
        gate = self.track_gate if state_before == "tracking" else self.search_gate
        if gate is not None:
            gate()
        t0 = time.perf_counter()
        try:
            pp = cloud.pp if isinstance(cloud.pp, tuple) and len(cloud.pp) == 2 else None
            scan = pp[1] if pp is not None and pp[0] is self.localizer else cloud.xyz  # prepared for this map
            self.prepared += scan is not cloud.xyz
            res = tracker.step(scan, cloud.stamp_ns, cloud.times)
        except LocalizationError as err:
            raise BadInput("localization_failed", str(err)) from err
        timings = {"register": (time.perf_counter() - t0) * 1e3}
        for k, v in (res.timings_ms or {}).items():
            if k != "total":
                timings[f"register.{k}"] = float(v)
        T = np.asarray(res.T_map_scan, dtype=np.float64)
        valid = bool(res.valid) and T.shape == (4, 4) and bool(np.all(np.isfinite(T)))
        res.valid = valid
        line = self._account(res, T, valid, cloud, tracker)
        if valid and self._prefetch is not None and hasattr(self.localizer, "prefetch"):
            ahead = tracker.predict(cloud.stamp_ns + int(PREFETCH_AHEAD_S * 1e9))
            if ahead is not None:
                self._prefetch.submit((self.localizer, ahead))
        self._bridge.forget_until(cloud.stamp_ns)
        if not self._bridging:
            self._say_drops(cloud.stamp_ns)
        reg = Registered(T, res, timings)
        return LocalizedScan(res, reg, getattr(res, "crop", None), self.map.frame_id, line)

    def _prefetch_crop(self, job: tuple[Any, np.ndarray]) -> None:
        localizer, T = job
        if localizer.prefetch(T) >= 0:
            self.prefetched += 1

    def stop(self) -> None:
        """Stop the prefetch thread (the crop it prepares, if any, is finished first)."""
        if self._prefetch is not None:
            self._prefetch.stop()
