"""The odometry's motion model: constant velocity, scaled to the stamp gap (no ROS import).

``T_map_k = T_map_{k-1} @ delta^(dt / period)``: ``delta`` is the last motion per nominal period, the period the first
stamp interval (or a shorter one, which shows that a scan was missing before it); ``deskew_delta`` the mean of the last
``odometry.deskew_window`` motions, which the deskew uses.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["MotionModel", "se3_power"]


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


class MotionModel:
    """Constant velocity per nominal scan period.

    Args:
        gap_factor: a stamp interval above this many periods is a gap (``odometry.gap_factor``); one below its inverse
            becomes the new period.
        window: motions averaged for the deskew (``odometry.deskew_window``).
    """

    def __init__(self, gap_factor: float, window: int) -> None:
        self.gap_factor = gap_factor
        self.delta = np.eye(4)  # last motion per nominal period
        self.period = 0.0  # nominal scan period (s), from the stamps
        self.prev_stamp: int | None = None
        self.deltas: deque[np.ndarray] = deque(maxlen=max(1, window))

    def time_scale(self, stamp_ns: int | None) -> tuple[float, bool]:
        """(dt / nominal period, stamp gap?) from the stamps; (1, False) without stamps."""
        if stamp_ns is None or self.prev_stamp is None:
            return 1.0, False
        dt = (int(stamp_ns) - self.prev_stamp) * 1e-9
        if dt <= 0:
            return 1.0, False
        if self.period <= 0:
            self.period = dt  # the first interval defines the nominal period ...
            return 1.0, False
        scale = dt / self.period
        if scale < 1.0 / self.gap_factor:
            # ... until a shorter one shows that a frame was missing before: the velocity so far was per the old
            # period, rescale it to the new one (left as it was, the next prediction is period_old / dt times too far:
            # metres on a recording whose first interval was long)
            self.period = dt
            self.delta = se3_power(self.delta, scale)
            self.deltas = deque((se3_power(d, scale) for d in self.deltas), maxlen=self.deltas.maxlen)
            return 1.0, False
        return max(scale, 1e-3), scale > self.gap_factor

    def predict(self, pose: np.ndarray, scale: float) -> np.ndarray:
        """The constant-velocity prediction (4, 4) ``scale`` periods after ``pose``."""
        return pose @ se3_power(self.delta, scale)

    def update(self, T_prev_k: np.ndarray, scale: float) -> None:
        """Learn the motion ``T_prev_k`` (4, 4) made in ``scale`` periods."""
        self.delta = se3_power(T_prev_k, 1.0 / scale) if scale != 1.0 else T_prev_k
        self.deltas.append(self.delta)

    def deskew_delta(self) -> np.ndarray:
        """The motion per period the deskew uses: the mean of the last ``window`` motions.

        Deskewing with the last motion alone feeds the pose error back with gain -1 (a scan deskewed with
        a velocity too high by e lands e T / 2 short, which lowers the next velocity by e: an undamped
        period-2 oscillation that diverged on the simulated drives); averaging m motions damps it."""
        from scipy.spatial.transform import Rotation

        ds = list(self.deltas) or [self.delta]
        w = np.mean([Rotation.from_matrix(d[:3, :3]).as_rotvec() for d in ds], axis=0)
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(w).as_matrix()
        out[:3, 3] = np.mean([d[:3, 3] for d in ds], axis=0)
        return out
