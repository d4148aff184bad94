"""DeepBBS++ odometry: scan-to-local-map ICP (KISS-ICP's pipeline) with DeepBBS++ where the motion prior fails.

``DeepBBSOdometry.register_frame`` reads top-down, as kiss-icp's ``register_frame``::

    deskew      per-point times (Velodyne ``time``, Ouster ``t``) + the constant-velocity twist -> the scan at its stamp
    voxelize    crop, two voxel grids (KISS-ICP's: 0.5 x and 1.5 x ``voxel_size``)
    predict     constant velocity scaled to the stamp gap: T_map_k = T_map_{k-1} @ delta^(dt / period)
    align       point-to-point ICP of the scan against the local voxel map from the prediction, adaptive threshold
    check       fit = share of scan points within ``fit_radius`` of the previous scan; on a stamp gap, a fit drop
                or the first motion, DeepBBS++ registers the scan against the previous one (wide basin) and
                the map alignment runs again from there (first motion: the GICP-precise DeepBBS++ result
                itself, the map being the first scan); the start with the clearly better fit wins
    update      adaptive threshold (deviation from the prediction that won), map, velocity

Why: KISS-ICP's scan-to-map ICP is the most precise odometry on ordinary drives, and its constant-velocity
prediction is exactly what breaks on dropped frames, sharp turns at low frame rates and a wrong prior;
DeepBBS++ needs no prior. On ordinary frames DeepBBS++ does not run, so the pipeline costs KISS-ICP's
time plus the fit check.

Frames and conventions (CONVENTIONS.md): the map frame is the first scan's sensor frame at its stamp;
``register_frame`` returns ``T_first_k`` (4, 4) float64, the pose of scan k's sensor at its stamp in that
frame; ``T_{k-1}_k = inv(T_first_{k-1}) @ T_first_k``. Components from ``kiss_icp`` (voxel hash map,
registration, adaptive threshold, voxelisation, range crop); no ROS import.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.errors import RegistrationError

__all__ = ["DeepBBSOdometry", "OdometryStep", "se3_power", "deskew"]


def se3_power(T: np.ndarray, a: float) -> np.ndarray:
    """``exp(a log T)`` for a rigid transform (4, 4): the same screw motion, ``a`` times as far."""
    if a == 1.0:
        return np.array(T, dtype=np.float64, copy=True)
    if a == 0.0:
        return np.eye(4)
    if a < 0:  # the inverse of the forward motion (exact)
        P = se3_power(T, -a)
        out = np.eye(4)
        out[:3, :3] = P[:3, :3].T
        out[:3, 3] = -P[:3, :3].T @ P[:3, 3]
        return out
    from scipy.spatial.transform import Rotation

    R, t = T[:3, :3], T[:3, 3]
    w = Rotation.from_matrix(R).as_rotvec()
    th = float(np.linalg.norm(w))
    V = _left_jacobian(w, th)
    u = np.linalg.solve(V, t)  # translational part of the twist
    w2 = a * w
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(w2).as_matrix()
    out[:3, 3] = _left_jacobian(w2, a * th) @ (a * u)
    return out


def _left_jacobian(w: np.ndarray, th: float) -> np.ndarray:
    """SO(3) left Jacobian V(w) (3, 3): t = V u for the twist (w, u)."""
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-9:
        return np.eye(3) + 0.5 * K
    return np.eye(3) + (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * (K @ K)


def deskew(points: np.ndarray, times: np.ndarray, delta: np.ndarray, period: float) -> np.ndarray:
    """Motion compensation to the scan stamp under constant velocity.

    Args:
        points: (N, 3) xyz, each in the sensor frame at its own time, metres.
        times: (N,) seconds since the scan stamp (negative before it).
        delta: (4, 4) the last motion ``T_{k-1}_k`` over ``period`` seconds (body frame).
    Returns:
        (N, 3) float64: ``p_stamp = T_stamp_t p`` with ``T_stamp_t = exp(t / period * log delta)``;
        rotation exact (Rodrigues per point), translation to first order in the rotation.
    """
    from scipy.spatial.transform import Rotation

    w = Rotation.from_matrix(delta[:3, :3]).as_rotvec() / period  # rad/s
    v = delta[:3, 3] / period  # m/s
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1, 1)
    speed = float(np.linalg.norm(w))
    out = p + t * v
    if speed < 1e-12:
        return out
    k = w / speed
    th = t * speed
    c, s = np.cos(th), np.sin(th)
    kxp = np.cross(k, p)
    kdp = p @ k
    return out + (c - 1.0) * p + s * kxp + (1.0 - c) * kdp[:, None] * k


@dataclass
class OdometryStep:
    """One frame of :class:`DeepBBSOdometry`.

    T_first_k: (4, 4) float64 pose of the scan (at its stamp) in the first scan's frame.
    T_prev_k: (4, 4) float64 motion since the previous frame (``T_{k-1}_k``).
    deepbbs: DeepBBS++ was consulted (why in ``reason``); won: its start was kept (first motion: its fit
        was not worse than identity's by more than ``odometry.fit_margin``; later: better than the
        prediction's by more than that).
    fit: share of scan points within ``odometry.fit_radius`` of the previous scan after alignment.
    timings_ms: "deskew", "align", "check", "deepbbs" (0 when not consulted), "total".
    """

    T_first_k: np.ndarray
    T_prev_k: np.ndarray
    deepbbs: bool = False
    won: bool = False
    reason: str = ""
    fit: float = float("nan")
    timings_ms: dict[str, float] = field(default_factory=dict)


class DeepBBSOdometry:
    """Scan-to-local-map odometry with DeepBBS++ as the initialiser where the motion prior fails.

    Args:
        config: ``preprocess.min_range``/``max_range`` (crop), the ``odometry`` section, and for DeepBBS++
            the ``preprocess``/``model``/``registration`` sections.
        registration: a :class:`~deepbbs_ros.core.registration.DeepBBSRegistration` to use (shared with
            other users of the same network); built from ``config`` on first need when None, unless
            ``odometry.deepbbs_init`` is "never".
    """

    def __init__(self, config: Config | None = None, registration: Any = None) -> None:
        from kiss_icp.mapping import VoxelHashMap
        from kiss_icp.preprocess import Preprocessor
        from kiss_icp.registration import Registration
        from kiss_icp.threshold import AdaptiveThreshold

        self.config = (config or Config()).validate()
        pp, oc = self.config.preprocess, self.config.odometry
        self.voxel_size = oc.voxel_size if oc.voxel_size > 0 else pp.max_range / 100.0
        self._crop = Preprocessor(pp.max_range, pp.min_range, False, oc.threads)
        self._map = VoxelHashMap(self.voxel_size, pp.max_range, oc.max_points_per_voxel)
        self._icp = Registration(oc.max_icp_iters, 1e-4, oc.threads)
        self._threshold = AdaptiveThreshold(_KissThresholdConfig(oc.initial_threshold, oc.min_motion_th, pp.max_range))
        self._reg = registration
        self.reset()

    def reset(self) -> None:
        """Forget the map and the motion: the next scan becomes the origin."""
        if getattr(self, "_map", None) is not None:
            self._map.clear()
        self.frames = 0
        self.pose = np.eye(4)  # T_first_{k-1}
        self.delta = np.eye(4)  # last motion per nominal period
        self.period = 0.0  # nominal scan period (s), from the stamps
        self._prev_stamp: int | None = None
        self._prev_tree: Any = None
        self._prev_points: np.ndarray | None = None
        self._prev_pp: Any = None
        self._first_raw: tuple[np.ndarray, np.ndarray] | None = None
        self._fits: deque[float] = deque(maxlen=max(1, self.config.odometry.fit_window))
        self.deepbbs_calls = 0

    @property
    def registration(self) -> Any:
        """The DeepBBS++ registration (built on first use)."""
        if self._reg is None:
            from deepbbs_ros.core.registration import DeepBBSRegistration

            self._reg = DeepBBSRegistration(self.config)
            self._reg.warmup()
        return self._reg

    # -- the pipeline ------------------------------------------------------------------------------
    def register_frame(self, points: np.ndarray, times: np.ndarray | None = None,
                       stamp_ns: int | None = None) -> OdometryStep:
        """Add scan k: (N, 3) xyz in its sensor frame (metres, NaN allowed), optional (N,) per-point
        times in seconds since ``stamp_ns`` (the scan stamp, ns). Returns the :class:`OdometryStep`."""
        clock = _Laps()
        oc = self.config.odometry
        scale, gap = self._time_scale(stamp_ns)
        frame = self._deskew(points, times, scale)
        clock.lap("deskew")
        source, frame_down = self._voxelize(frame)
        if self.frames == 0:
            return self._first(frame, frame_down, stamp_ns, clock, points, times)
        # predict + align: KISS-ICP from the constant-velocity prediction, scaled to the stamp gap
        sigma = float(self._threshold.get_threshold())
        prior = self.pose @ se3_power(self.delta, scale)
        pose = self._align(source, prior, sigma)
        clock.lap("align")
        fit = self._fit(source, pose)
        clock.lap("check")
        # check: DeepBBS++ where the prior is suspect
        reason = self._suspect(gap, fit)
        won, init = False, prior
        if reason:
            T_prev_k = self._deepbbs(frame, points)
            if T_prev_k is not None:
                init_b = self.pose @ T_prev_k
                if self.frames == 1:  # the map is the first scan: DeepBBS++ (GICP-precise) is scan-to-map
                    pose_b = init_b
                else:
                    pose_b = self._align(source, init_b, oc.reinit_threshold)
                fit_b = self._fit(source, pose_b)
                # first motion: there is no prior yet (identity is a guess), DeepBBS++ wins unless clearly
                # worse; later the constant-velocity track wins unless DeepBBS++ fits clearly better
                better = fit_b + oc.fit_margin >= fit if self.frames == 1 else fit_b > fit + oc.fit_margin
                if better:
                    pose, fit, init, won = pose_b, fit_b, init_b, True
            clock.lap("deepbbs")
        T_prev_k = np.linalg.inv(self.pose) @ pose
        self.delta = se3_power(T_prev_k, 1.0 / scale) if scale != 1.0 else T_prev_k
        if self.frames == 1 and self._first_raw is not None and self._has_times(times):
            # the first velocity is known only now: deskew the first two scans with it and restart the map
            frame, frame_down, pose, T_prev_k = self._restart_deskewed(points, times, pose, sigma)
            clock.lap("align")
        # update: threshold (deviation from the start that won), map, velocity, previous scan
        self._threshold.update_model_deviation(np.linalg.inv(init) @ pose)
        self._map.update(frame_down, pose)
        self.pose = pose
        self._fits.append(fit)
        self._remember(frame, frame_down, stamp_ns, points if reason else None)
        self.frames += 1
        return OdometryStep(pose.copy(), T_prev_k, bool(reason), won, reason, fit, clock.done())

    # -- stages ------------------------------------------------------------------------------------
    def _time_scale(self, stamp_ns: int | None) -> tuple[float, bool]:
        """(dt / nominal period, stamp gap?) from the stamps; (1, False) without stamps."""
        if stamp_ns is None or self._prev_stamp is None:
            return 1.0, False
        dt = (int(stamp_ns) - self._prev_stamp) * 1e-9
        if dt <= 0:
            return 1.0, False
        if self.period <= 0:
            self.period = dt  # the first interval defines the nominal period ...
            return 1.0, False
        scale = dt / self.period
        if scale < 1.0 / self.config.odometry.gap_factor:
            self.period = dt  # ... until a shorter one shows that a frame was missing before
        return max(scale, 1e-3), scale > self.config.odometry.gap_factor

    def _has_times(self, times: np.ndarray | None) -> bool:
        return bool(self.config.odometry.deskew and times is not None and len(times) and np.ptp(times) > 0)

    def _deskew(self, points: np.ndarray, times: np.ndarray | None, scale: float,
                delta: np.ndarray | None = None) -> np.ndarray:
        """Finite points, deskewed to the stamp with ``delta`` (default: the velocity so far, from the
        third scan on), cropped: (N, 3) float64."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        ok = np.isfinite(pts).all(axis=1)
        if not ok.all():
            pts = pts[ok]
        if delta is None and self.frames >= 2 and self.period > 0:
            delta = self.delta
        if delta is not None and self._has_times(times):
            tt = np.asarray(times, dtype=np.float64).reshape(-1)
            if len(tt) == len(ok):
                pts = deskew(pts, tt[ok], delta, self.period)
        frame = self._crop.preprocess(pts, np.zeros(len(pts)), np.eye(4))
        if len(frame) < 10:
            raise RegistrationError(f"odometry: only {len(frame)} valid points within the crop range")
        return frame

    def _voxelize(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """KISS-ICP's two grids: (source for ICP at 1.5 x voxel, map points at 0.5 x voxel)."""
        from kiss_icp.voxelization import voxel_down_sample

        frame_down = voxel_down_sample(frame, self.voxel_size * 0.5)
        return voxel_down_sample(frame_down, self.voxel_size * 1.5), frame_down

    def _align(self, source: np.ndarray, init: np.ndarray, sigma: float) -> np.ndarray:
        return np.asarray(self._icp.align_points_to_map(
            points=source, voxel_map=self._map, initial_guess=init,
            max_correspondance_distance=3.0 * sigma, kernel=sigma))  # fmt: skip

    def _fit(self, source: np.ndarray, pose: np.ndarray) -> float:
        """Share of the scan's ICP points within ``fit_radius`` of the previous scan, under ``pose``."""
        T = np.linalg.inv(self.pose) @ pose  # T_{k-1}_k
        moved = np.ascontiguousarray(source @ T[:3, :3].T + T[:3, 3])
        _, d2 = self._prev_tree.batch_nearest_neighbor_search(moved, num_threads=2)
        r = self.config.odometry.fit_radius
        return float(np.mean(np.asarray(d2) <= r * r))

    def _suspect(self, gap: bool, fit: float) -> str:
        """Why DeepBBS++ should check this frame ("" = it should not)."""
        oc = self.config.odometry
        if oc.deepbbs_init == "never":
            return ""
        if oc.deepbbs_init == "always":
            return "always"
        if gap:
            return "stamp gap"
        if self.frames == 1:
            return "first motion"
        if len(self._fits) >= 3 and fit < oc.fit_drop * float(np.median(self._fits)):
            return f"fit {fit:.2f} < {oc.fit_drop} x median {float(np.median(self._fits)):.2f}"
        return ""

    def _deepbbs(self, frame: np.ndarray, raw: np.ndarray) -> np.ndarray | None:
        """DeepBBS++ ``T_{k-1}_k`` of the (deskewed) scan against the previous one; None if it fails."""
        reg = self.registration
        try:
            if self._prev_pp is None and self._prev_points is not None:
                self._prev_pp = reg.preprocess(self._prev_points.astype(np.float32))
            cur = reg.preprocess(frame.astype(np.float32))
            if self._prev_pp is None:
                return None
            res = reg.register(cur, self._prev_pp)
        except RegistrationError:
            return None
        self._cur_pp = cur
        self.deepbbs_calls += 1
        return res.T_target_source

    def _restart_deskewed(self, points, times, pose, sigma):
        """Second scan: both scans deskewed with the first velocity, the map rebuilt from them, the second
        scan aligned again (a map of distorted first scans would bias every later deskewed scan)."""
        raw0, times0 = self._first_raw
        self._first_raw = None
        first = self._deskew(raw0, times0, 1.0, self.delta)
        self._map.clear()
        self._map.update(self._voxelize(first)[1], np.eye(4))
        frame = self._deskew(points, times, 1.0, self.delta)
        source, frame_down = self._voxelize(frame)
        pose = self._align(source, pose, sigma)
        T_prev_k = np.linalg.inv(self.pose) @ pose
        self.delta = T_prev_k
        return frame, frame_down, pose, T_prev_k

    def _first(self, frame, frame_down, stamp_ns, clock, points=None, times=None) -> OdometryStep:
        self._first_raw = (np.asarray(points), np.asarray(times)) if self._has_times(times) else None
        self._map.update(frame_down, np.eye(4))
        self._remember(frame, frame_down, stamp_ns, None)
        self.frames = 1
        return OdometryStep(np.eye(4), np.eye(4), timings_ms=clock.done())

    def _remember(self, frame, frame_down, stamp_ns, consulted) -> None:
        import small_gicp

        pts = np.ascontiguousarray(frame_down, dtype=np.float64)
        self._prev_tree = small_gicp.KdTree(pts, num_threads=2)
        self._prev_points = frame
        self._prev_pp = getattr(self, "_cur_pp", None) if consulted is not None else None
        self._cur_pp = None
        self._prev_stamp = None if stamp_ns is None else int(stamp_ns)


@dataclass
class _KissThresholdConfig:
    """The attributes of KISSConfig that kiss_icp's AdaptiveThreshold reads."""

    initial_threshold: float
    min_motion_th: float
    max_range: float

    @property
    def adaptive_threshold(self) -> _KissThresholdConfig:
        return self

    @property
    def data(self) -> _KissThresholdConfig:
        return self


class _Laps:
    def __init__(self) -> None:
        self.t0 = self.t = time.perf_counter()
        self.ms: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.ms[name] = self.ms.get(name, 0.0) + (now - self.t) * 1e3
        self.t = now

    def done(self) -> dict[str, float]:
        self.ms["total"] = (time.perf_counter() - self.t0) * 1e3
        return self.ms
