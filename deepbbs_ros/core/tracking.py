"""Tracking a scan stream in a prior map (no ROS): :class:`MapTracker`, the state machine around
:class:`~deepbbs_ros.core.localization.MapLocalizer` shared by the node and the replay.

Constant-velocity prediction from the last accepted poses, tracking from it, from the last pose at rest or from the
prediction mirrored (turned back), whichever the scan fits best (``MapLocalizer.localize`` with a guess and those
starts), lost after ``localization.lost_after`` rejected scans (or an implausible speed), then the global search until
found again; a pose hint (:meth:`MapTracker.hint`, core/pose_hint.py) searches near it first. ``MapTracker.motion``
gives the sensor's recent motion for deskewing the next scan.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.localization_types import LocalizationResult, PreparedScan
from deepbbs_ros.core.pose_hint import (  # noqa: F401  (the hint's constants re-exported)
    HINT_MIN_RADIUS,
    HINT_MIN_YAW,
    HINT_SIGMAS,
    HINT_YAW_STEP,
    HintSteps,
)

if TYPE_CHECKING:
    from deepbbs_ros.core.map_localizer import MapLocalizer

#: accepted poses the tracker keeps; the deskew motion is their mean over the window (MapTracker.motion)
DESKEW_WINDOW = 5


class MapTracker(HintSteps):
    """The state machine shared by the node and the replay (module docstring).

    One scan in -> one :class:`LocalizationResult` out with its ``event``: "found" (first pose), "tracking",
    "lost" (``lost_after`` rejected scans in a row, or a pose implying more than ``max_speed``), "searching" (no
    pose yet, or still lost), "relocalized" (found again after being lost). ``state``: "searching" | "tracking" |
    "lost"; ``recoveries``: times it was lost and found again.
    """

    def __init__(self, localizer: MapLocalizer, config: Config | None = None) -> None:
        self.localizer = localizer
        self.config = config if config is not None else localizer.config
        self.recoveries = 0
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next scan is searched in the whole map (the node's ~/relocalize)."""
        self.state = "searching"
        self.rejected = 0
        self._poses: list[tuple[int, np.ndarray]] = []  # (stamp_ns, T_map_scan) of the last accepted scans
        self._hint: tuple[np.ndarray, float, float] | None = None  # hint(): pose, radius (m), yaw window (rad)

    @property
    def last_stamp_ns(self) -> int | None:
        """The stamp of the last accepted scan (ns), None with none since the last reset."""
        poses = self._poses
        return poses[-1][0] if poses else None

    def predict(self, stamp_ns: int) -> np.ndarray | None:
        """T_map_scan (4, 4) at ``stamp_ns`` under constant velocity from the last two accepted poses (the last pose
        with one; None with none)."""
        if not self._poses:
            return None
        step = self._step_to(stamp_ns)
        return self._poses[-1][1] @ step if step is not None else self._poses[-1][1].copy()

    def _step_to(self, stamp_ns: int) -> np.ndarray | None:
        """The motion T_last_scan (4, 4) from the last accepted pose to ``stamp_ns`` under constant velocity (the last
        step scaled to the time); None with fewer than two poses or a gap of more than five steps (no velocity)."""
        if len(self._poses) < 2:
            return None
        (s0, T0), (s1, T1) = self._poses[-2], self._poses[-1]
        dt0, dt1 = (s1 - s0) * 1e-9, (stamp_ns - s1) * 1e-9
        if dt0 <= 0 or dt1 < 0 or dt1 > 5.0 * max(dt0, 0.05):
            return None
        from scipy.spatial.transform import Rotation

        step = np.linalg.inv(T0) @ T1
        k = dt1 / dt0
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(Rotation.from_matrix(step[:3, :3]).as_rotvec() * k).as_matrix()
        out[:3, 3] = step[:3, 3] * k
        return out

    def step(self, scan: Any, stamp_ns: int, times: np.ndarray | None = None) -> LocalizationResult:
        """Localize one scan (N, 3) (sensor frame, metres; or its :class:`PreparedScan`, deskewed already) stamped
        ``stamp_ns`` (per-point ``times`` (N,) s since the stamp, optional). Raises LocalizationError for bad input
        (the state is unchanged)."""
        lc = self.config.localization
        stamp_ns = int(stamp_ns)
        if self.state == "tracking":
            guess = self.predict(stamp_ns)
            motion = self.motion() if times is not None else None
            # beside the constant-velocity prediction, the same velocity's other two signs: the last pose at rest (a
            # sensor that stopped, or a prediction across a gap) and the prediction mirrored (a sensor that turned back
            # and retraces its path); GICP from whichever of them the scan fits best (measured on the map, a few
            # hundred points each: core/guess_tracking.py), not the slower DeepBBS++ path
            last, step = self._poses[-1][1], self._step_to(stamp_ns)
            starts = [last] if len(self._poses) >= 2 and not np.array_equal(guess, last) else []
            if starts and step is not None:
                starts.append(last @ np.linalg.inv(step))
            res = self.localizer.localize(scan, guess, times=times, stamp_ns=stamp_ns, motion=motion, starts=starts)
            if res.valid and not self._plausible(res.T_map_scan, stamp_ns):
                res.valid = False
                res.reason = f"implausible motion (faster than {lc.max_speed:.0f} m/s)"
            if res.valid:
                self.rejected = 0
                self._accept(stamp_ns, res.T_map_scan)
                res.event = "tracking"
                return res
            self.rejected += 1
            if self.rejected >= lc.lost_after:
                self.state = "lost"
                self._poses.clear()
                res.event = "lost"
            else:
                res.event = "tracking"
            return res
        res = None
        if self._hint is not None:
            if not isinstance(scan, PreparedScan):
                scan = self.localizer.prepare(scan, times, stamp_ns)  # once for the hint's searches and the map's
            res = self._step_hint(scan)
        if res is None:
            res = self.localizer.localize(scan, None, times=times, stamp_ns=stamp_ns)
        if res.valid:
            res.event = "relocalized" if self.state == "lost" else "found"
            if self.state == "lost":
                self.recoveries += 1
            self.state, self.rejected = "tracking", 0
            self._accept(stamp_ns, res.T_map_scan)
        else:
            res.event = "searching"
        return res

    def motion(self) -> tuple[np.ndarray, float] | None:
        """The sensor's recent motion (``T_prev_cur`` (4, 4), seconds) over the last ``DESKEW_WINDOW`` accepted poses
        while tracking (deskewing a scan: :meth:`MapLocalizer.prepare`), else None. Safe to call from another thread.
        A window, not the last step: the deskew's motion is read off map poses that it shapes, and from two poses the
        loop amplifies their noise (a raw-sweep drive: tilt 0.1 -> 7 deg in 25 scans, the verdict still at 0.99)."""
        poses = list(self._poses)  # one read: the list may be appended to meanwhile
        if self.state != "tracking" or len(poses) < 2:
            return None
        (s0, T0), (s1, T1) = poses[0], poses[-1]
        return np.linalg.inv(T0) @ T1, (s1 - s0) * 1e-9

    def _plausible(self, T: np.ndarray, stamp_ns: int) -> bool:
        if not self._poses:
            return True
        s1, T1 = self._poses[-1]
        dt = max((stamp_ns - s1) * 1e-9, 0.05)
        return float(np.linalg.norm(T[:3, 3] - T1[:3, 3])) <= self.config.localization.max_speed * dt + 1.0

    def _accept(self, stamp_ns: int, T: np.ndarray) -> None:
        self._poses.append((stamp_ns, T.copy()))
        del self._poses[:-DESKEW_WINDOW]
