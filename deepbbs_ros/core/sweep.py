"""A sweep's motion: per-point times from the azimuth, constant-velocity deskew to the stamp (no ROS import).

:class:`SweepTimes` gives per-point times to points that lost theirs (a spinning sensor measures each azimuth at a
known time); :func:`deskew` moves every point to the scan stamp under a constant body twist.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def deskew(points: np.ndarray, times: np.ndarray, delta: np.ndarray, period: float) -> np.ndarray:
    """Motion compensation to the scan stamp under constant velocity.

    Args:
        points: (N, 3) xyz, each in the sensor frame at its own time, metres.
        times: (N,) seconds since the scan stamp (negative before it).
        delta: (4, 4) a motion ``T_{a}_{b}`` of the sensor over ``period`` seconds (b later than a when
            ``period`` > 0), e.g. the last odometry step ``T_{k-1}_k``: the constant body twist is
            ``log(delta) / period``.
    Returns:
        (N, 3) float64: ``p_stamp = T_stamp_t p`` with ``T_stamp_t = exp(t / period * log delta)``;
        rotation exact (Rodrigues per point), translation to first order in the rotation.
    """
    from scipy.spatial.transform import Rotation

    w = Rotation.from_matrix(delta[:3, :3]).as_rotvec() / period  # rad/s
    v = delta[:3, 3] / period  # m/s
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    out = np.empty((len(p), 3))
    speed = float(np.linalg.norm(w))
    if speed < 1e-12:
        for i in range(3):
            out[:, i] = p[:, i] + t * v[i]
        return out
    # Rodrigues column by column (no (N, 3) temporaries, no np.cross): 2.5x faster on a 120k-point scan, same numbers
    kx, ky, kz = w / speed
    th = t * speed
    c, s = np.cos(th), np.sin(th)
    akdp = (1.0 - c) * (x * kx + y * ky + z * kz)
    out[:, 0] = c * x + s * (ky * z - kz * y) + akdp * kx + t * v[0]
    out[:, 1] = c * y + s * (kz * x - kx * z) + akdp * ky + t * v[1]
    out[:, 2] = c * z + s * (kx * y - ky * x) + akdp * kz + t * v[2]
    return out


@dataclass(frozen=True)
class SweepTimes:
    """The time at which a spinning LiDAR measures each azimuth: ``t = t_min + ((direction (az0 - az))
    mod 2 pi) / (2 pi) * period`` (az = atan2(y, x) in the sensor frame). It gives per-point times to
    points that lost theirs, e.g. the voxel centroids of the precision stage's clouds."""

    az0: float  # rad, azimuth measured first
    direction: int  # +1 clockwise seen from above (Velodyne), -1 counter-clockwise
    t_min: float  # s since the stamp
    period: float  # s per revolution

    MAX_POINTS = 20000  # points used by the fit (an even subsample)

    @classmethod
    def fit(cls, points: np.ndarray, times: np.ndarray) -> SweepTimes | None:
        """Fit to a scan (N, 3) with per-point ``times`` (N,) s; None when the times do not follow the
        azimuth (median residual above 2 % of the sweep: not a spinning sensor, or a scrambled field)."""
        step = max(1, len(points) // cls.MAX_POINTS)
        p = np.asarray(points[::step], dtype=np.float64)
        t = np.asarray(times[::step], dtype=np.float64)
        ok = np.isfinite(p).all(axis=1) & np.isfinite(t) & ((p[:, 0] ** 2 + p[:, 1] ** 2) > 1e-6)
        p, t = p[ok], t[ok]
        if len(t) < 100 or np.ptp(t) <= 0:
            return None
        az = np.arctan2(p[:, 1], p[:, 0])
        t_min, span = float(t.min()), float(np.ptp(t))
        first = t <= t_min + 0.005 * span
        az0 = float(np.angle(np.mean(np.exp(1j * az[first]))))
        best = None
        for direction in (1, -1):
            model = cls(az0, direction, t_min, span)
            res = float(np.median(np.abs(model(p) - t)))
            if best is None or res < best[0]:
                best = (res, model)
        return best[1] if best[0] <= 0.02 * span else None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64 times of the points (N, 3) from their azimuths."""
        az = np.arctan2(points[:, 1], points[:, 0])
        return self.t_min + np.mod(self.direction * (self.az0 - az), 2 * np.pi) / (2 * np.pi) * self.period

