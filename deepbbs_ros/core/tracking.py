"""Tracking a scan stream in a prior map (no ROS): :class:`MapTracker`, the state machine around
:class:`~deepbbs_ros.core.localization.MapLocalizer` shared by the node and the replay.

Constant-velocity prediction from the last accepted poses, tracking from it, from the last pose at rest or from the
prediction mirrored (turned back), whichever the scan fits best (``MapLocalizer.localize`` with a guess and those
starts), lost after ``localization.lost_after`` rejected scans (or an implausible speed), then the global search until
found again; a pose hint (:meth:`MapTracker.hint`) searches near it first. ``MapTracker.motion`` gives the sensor's
recent motion for deskewing the next scan.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.localization_types import LocalizationResult, PreparedScan, _yaw
from deepbbs_ros.errors import LocalizationError

if TYPE_CHECKING:
    from deepbbs_ros.core.map_localizer import MapLocalizer

#: accepted poses the tracker keeps; the deskew motion is their mean over the window (MapTracker.motion)
DESKEW_WINDOW = 5
#: MapTracker.hint: the places within this many standard deviations of the hint's position are searched first, and an
#: answer within as many of its yaw accepted; at least HINT_MIN_RADIUS m / HINT_MIN_YAW rad (an exact hint)
HINT_SIGMAS, HINT_MIN_RADIUS, HINT_MIN_YAW = 3.0, 10.0, np.radians(30.0)
#: MapTracker.hint: DeepBBS++ starts from the hint's yaw, and this far apart either side within its yaw window
HINT_YAW_STEP = np.radians(45.0)


class MapTracker:
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

    def hint(self, T_map_scan: np.ndarray, covariance: np.ndarray | None = None) -> None:
        """A pose hint (an operator's initial pose, RViz's "2D Pose Estimate"): forget the pose, and the next
        :meth:`step` registers the scan from the hint (:meth:`MapLocalizer.localize_near`: its yaw, and
        ``HINT_YAW_STEP`` steps within ``HINT_SIGMAS`` sigma of it), then searches the places within ``HINT_SIGMAS``
        standard deviations of its position (at least ``HINT_MIN_RADIUS`` m), accepting an answer only within that reach
        and ``HINT_SIGMAS`` sigma of its yaw (at least ``HINT_MIN_YAW``); when the verdict rejects there, the whole map.
        ``T_map_scan`` (4, 4); ``covariance`` (6, 6) x y z rot x rot y rot z (None: the minimum reach)."""
        T = np.asarray(T_map_scan, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise LocalizationError(f"hint: expected a finite (4, 4) T_map_scan, got shape {T.shape}")
        cov = np.zeros((6, 6)) if covariance is None else np.nan_to_num(np.asarray(covariance, dtype=np.float64))
        sigma_xy = float(np.sqrt(max(cov[0, 0], cov[1, 1], 0.0)))
        sigma_yaw = float(np.sqrt(max(cov[5, 5], 0.0)))
        self.reset()
        self._hint = (T, max(HINT_SIGMAS * sigma_xy, HINT_MIN_RADIUS), max(HINT_SIGMAS * sigma_yaw, HINT_MIN_YAW))

    def _step_hint(self, scan: Any) -> LocalizationResult | None:
        """The search near a pending :meth:`hint` (consumed) for a :class:`PreparedScan`: DeepBBS++ from the hint,
        then the places within its reach; the result when the verdict accepts a pose within its reach, else None (the
        caller searches the whole map)."""
        T_hint, radius, max_yaw = self._hint
        self._hint = None
        # DeepBBS++ from the hint, at its yaw, then HINT_YAW_STEP either side within its window
        steps = np.arange(1, int(min(max_yaw, np.pi) / HINT_YAW_STEP) + 1) * HINT_YAW_STEP
        yaws = [0.0] + [s * y for y in steps for s in (1.0, -1.0)]
        res = self.localizer.localize_near(scan, T_hint, yaws)
        if res.valid and self._near(res, T_hint, radius, max_yaw):
            return res
        xy = self.localizer.places[:, :2, 3]
        d = np.linalg.norm(xy - T_hint[:2, 3], axis=1)
        among = np.flatnonzero(d <= radius)
        if len(among) == 0:
            among = np.argsort(d)[:1]  # the hint off the places: the nearest one
        res = self.localizer.localize(scan, None, among=among)
        if not res.valid or not self._near(res, T_hint, radius, max_yaw):
            return None  # no pose, or one outside the hint's reach: the whole map decides
        res.mode = "hint"
        return res

    @staticmethod
    def _near(res: LocalizationResult, T_hint: np.ndarray, radius: float, max_yaw: float) -> bool:
        """Whether a pose lies within a hint's reach: ``radius`` m and ``max_yaw`` rad of its yaw."""
        off = float(np.linalg.norm(res.T_map_scan[:2, 3] - T_hint[:2, 3]))
        turn = abs(float(np.angle(np.exp(1j * (_yaw(res.T_map_scan) - _yaw(T_hint))))))
        return off <= radius and (max_yaw >= np.pi or turn <= max_yaw)

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
