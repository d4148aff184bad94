"""How a sensor is carried: car roof, wheeled robot, legged robot, hand (no ROS).

:class:`MountTrajectory` moves a sensor along a path of waypoints on the floor and gives its
ground-truth pose ``T_world_lidar`` at any time (x forward, z up, REP-103). Motions per mount (the
numbers are drawn per seed from these ranges):

* ``car``: 2-4 m/s through a place (on the roads the drive simulator's own vehicle model is used),
  corners rounded over 10 m, sensor at its own ``mount_height`` (1.9 m by default), level;
* ``wheeled``: a ground robot, sensor 0.3-1.0 m above the floor, 0.5-1.2 m/s (0.5 m/s^2), planar (no roll
  or pitch), drives straight between corners (turns of more than 15 deg), stops there and turns in place at
  30-60 deg/s (90 deg/s^2);
* ``legged``: a quadruped, sensor 0.45-0.7 m high, 0.6-1.5 m/s, turning while it walks (corners over
  1.5 m), gait 1.5-2.5 Hz: pitch sway 1-3 deg at the gait frequency, roll sway 1.5-4 deg at half of it,
  height bob 1-2.5 cm;
* ``handheld``: walked at 0.5-1.2 m/s, sensor 1.1-1.5 m high, pointed forward and down (10-35 deg),
  slow random roll (+-10 deg) and pitch (+-6 deg) wobble, step bob 2-4 cm at 1.6-2.0 Hz, a slow aiming
  drift (5-15 deg), and about every 10 s a glance: the hand turns the sensor 30-60 deg aside and back
  in 1.5-2.5 s, at up to 90 deg/s.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.trajectory import euler_to_matrix

MOUNTS = ("car", "wheeled", "legged", "handheld")
DT = 0.01  # s, grid of the precomputed planar motion


def _trapezoid_duration(total: float, vmax: float, acc: float) -> float:
    """Seconds to cover ``total`` from rest to rest, accelerating at ``acc`` up to ``vmax``."""
    if total <= vmax * vmax / acc:  # triangular: never reaches vmax
        return 2.0 * np.sqrt(total / acc)
    return vmax / acc + total / vmax


def _trapezoid(e: np.ndarray, total: float, vmax: float, acc: float) -> np.ndarray:
    """Distance covered ``e`` seconds into a rest-to-rest move of ``total`` (see :func:`_trapezoid_duration`)."""
    dur = _trapezoid_duration(total, vmax, acc)
    t_acc = min(vmax / acc, dur / 2.0)
    v_peak = acc * t_acc
    e = np.clip(e, 0.0, dur)
    return np.where(e < t_acc, 0.5 * acc * e * e,
                    np.where(e < dur - t_acc, 0.5 * acc * t_acc * t_acc + v_peak * (e - t_acc),
                             total - 0.5 * acc * (dur - e) ** 2))


def _corners(pts: np.ndarray, min_turn_deg: float = 15.0) -> np.ndarray:
    """The waypoints where a dense path (a road's lane sampled every metre) turns by more than
    ``min_turn_deg`` since the last one kept: where a wheeled robot stops to turn in place."""
    keep = [0]
    for i in range(1, len(pts) - 1):
        a, b = pts[i] - pts[keep[-1]], pts[i + 1] - pts[i]
        turn = np.degrees(abs(np.angle(np.exp(1j * (np.arctan2(b[1], b[0]) - np.arctan2(a[1], a[0]))))))
        if turn > min_turn_deg:
            keep.append(i)
    keep.append(len(pts) - 1)
    return pts[keep]


def _loop(path: np.ndarray, closed: bool, laps: int) -> np.ndarray:
    pts = np.concatenate([path] * laps + [path[:1]]) if closed else path
    return np.asarray(pts, dtype=np.float64)


class MountTrajectory:
    """Poses of a sensor carried along ``path`` ((K, 2) waypoints; ``closed``: a loop, walked round and
    round) for ``duration`` s; ``floor(x, y)`` gives the floor height; ``sensor_height`` and
    ``sensor_pitch_deg`` are used by the ``car`` mount only (the others draw their own)."""

    def __init__(self, mount: str, path: np.ndarray, floor, seed: int, duration: float, *, closed: bool = True,
                 sensor_height: float = 1.9, sensor_pitch_deg: float = 0.0) -> None:
        if mount not in MOUNTS:
            raise SimulationError(f"unknown mount {mount!r}; choose one of {', '.join(MOUNTS)}")
        self.mount, self.floor, self.duration = mount, floor, float(duration)
        rng = np.random.default_rng([int(seed), 8111, MOUNTS.index(mount)])
        self.t_grid = np.arange(0.0, duration + 1.0, DT)
        speed = {"car": (2.0, 4.0), "wheeled": (0.5, 1.2), "legged": (0.6, 1.5), "handheld": (0.5, 1.2)}[mount]
        self.speed = float(rng.uniform(*speed))
        perimeter = float(np.sum(np.linalg.norm(np.diff(_loop(path, closed, 1), axis=0), axis=1)))
        laps = int(np.ceil(self.speed * (duration + 1.0) / max(perimeter, 1e-6))) + 1
        pts = _loop(path, closed, laps)
        if mount == "wheeled":
            self.xy, self.yaw = self._stop_and_turn(_corners(pts), rng)
        else:
            self.xy, self.yaw = self._walk(pts, {"car": 10.0, "legged": 1.5, "handheld": 2.5}[mount])
        if mount == "car":
            self.height, self.pitch0 = float(sensor_height), np.deg2rad(sensor_pitch_deg)
        elif mount == "wheeled":
            self.height, self.pitch0 = float(rng.uniform(0.3, 1.0)), np.deg2rad(sensor_pitch_deg)
        elif mount == "legged":
            self.height, self.pitch0 = float(rng.uniform(0.45, 0.7)), 0.0
            self.gait = float(rng.uniform(1.5, 2.5))
            self.sway = np.deg2rad([rng.uniform(1.0, 3.0), rng.uniform(1.5, 4.0)])  # pitch, roll amplitudes
            self.bob = float(rng.uniform(0.01, 0.025))
        else:
            self.height, self.pitch0 = float(rng.uniform(1.1, 1.5)), np.deg2rad(rng.uniform(10.0, 35.0))
            self.gait = float(rng.uniform(1.6, 2.0))
            self.bob = float(rng.uniform(0.02, 0.04))
            self.sweep = (np.deg2rad(rng.uniform(5.0, 15.0)), float(rng.uniform(0.1, 0.3)))  # slow aiming drift
            self.roll_waves = [(np.deg2rad(rng.uniform(2.0, 5.0)), rng.uniform(0.05, 0.3), rng.uniform(0, 6.3))
                               for _ in range(2)]
            self.pitch_waves = [(np.deg2rad(rng.uniform(1.0, 3.0)), rng.uniform(0.1, 0.6), rng.uniform(0, 6.3))
                                for _ in range(2)]
            # glances: the hand turns the sensor 30-60 deg aside and back, peak rate <= 90 deg/s, ~every 10 s
            starts = np.cumsum(rng.exponential(10.0, int(duration / 5.0) + 2))
            amps = rng.uniform(30.0, 60.0, len(starts)) * rng.choice([-1.0, 1.0], len(starts))
            lengths = np.maximum(rng.uniform(1.5, 2.5, len(starts)), np.abs(amps) * np.pi / 90.0)
            self.glances = np.stack([starts, np.deg2rad(amps), lengths], 1)
        self.phase = rng.uniform(0.0, 2 * np.pi, 3)

    # ---- planar motion -----------------------------------------------------------------------------
    def _walk(self, pts: np.ndarray, corner: float) -> tuple[np.ndarray, np.ndarray]:
        """Constant speed along the polyline with corners cut over ``corner`` metres (moving average)."""
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s_pts = np.concatenate([[0.0], np.cumsum(seg)])
        ds = 0.05
        s = np.arange(0.0, s_pts[-1], ds)
        dense = np.stack([np.interp(s, s_pts, pts[:, 0]), np.interp(s, s_pts, pts[:, 1])], 1)
        k = max(int(corner / ds), 1)
        kernel = np.ones(k) / k
        padded = np.concatenate([np.repeat(dense[:1], k, 0), dense, np.repeat(dense[-1:], k, 0)])
        sm = np.stack([np.convolve(padded[:, i], kernel, mode="same")[k:-k] for i in range(2)], 1)
        s_t = np.minimum(self.speed * self.t_grid + 0.5 * corner, s[-1])  # start past the smoothing's edge
        xy = np.stack([np.interp(s_t, s, sm[:, 0]), np.interp(s_t, s, sm[:, 1])], 1)
        d = np.gradient(sm, axis=0)
        heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        if s_t[-1] >= s[-1] - 1e-9:
            raise SimulationError("path too short for this drive (internal)")
        return xy, np.interp(s_t, s, heading)

    def _stop_and_turn(self, pts: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Drive each segment straight (trapezoidal speed: 0.5 m/s^2 up to ``speed``), stop, turn in place
        (90 deg/s^2 up to 30-60 deg/s), go on."""
        rate, acc_w, acc_v = np.deg2rad(rng.uniform(30.0, 60.0)), np.deg2rad(90.0), 0.5
        yaw0 = float(np.arctan2(pts[1, 1] - pts[0, 1], pts[1, 0] - pts[0, 0]))
        segs = []  # (start time, xy0, xy1, yaw0, yaw1, total, vmax, acc): one turn or one straight each
        t, yaw = 0.0, yaw0
        for a, b in zip(pts[:-1], pts[1:]):
            heading = float(np.arctan2(b[1] - a[1], b[0] - a[0]))
            turn = float(np.angle(np.exp(1j * (heading - yaw))))
            for xy1, yaw1, total, vmax, acc in ((a, yaw + turn, abs(turn), rate, acc_w),
                                                (b, yaw + turn, float(np.linalg.norm(b - a)), self.speed, acc_v)):
                segs.append((t, a, xy1, yaw, yaw1, total, vmax, acc))
                t += _trapezoid_duration(total, vmax, acc)
                yaw = yaw1
            if t > self.t_grid[-1]:
                break
        starts = np.array([sg[0] for sg in segs] + [np.inf])
        i = np.clip(np.searchsorted(starts, self.t_grid, side="right") - 1, 0, len(segs) - 1)
        xy, yaw_out = np.empty((len(self.t_grid), 2)), np.empty(len(self.t_grid))
        for k in np.unique(i):
            t0, xy0, xy1, y0, y1, total, vmax, acc = segs[k]
            m = i == k
            frac = _trapezoid(self.t_grid[m] - t0, total, vmax, acc) / max(total, 1e-12)
            xy[m] = xy0 + frac[:, None] * (np.asarray(xy1) - xy0)
            yaw_out[m] = y0 + frac * (y1 - y0)
        return xy, yaw_out

    # ---- poses -------------------------------------------------------------------------------------
    def poses(self, t: np.ndarray | float) -> np.ndarray:
        """(..., 4, 4) float64 ``T_world_lidar`` at times ``t`` (s since the start)."""
        t = np.asarray(t, dtype=np.float64)
        x = np.interp(t, self.t_grid, self.xy[:, 0])
        y = np.interp(t, self.t_grid, self.xy[:, 1])
        yaw = np.interp(t, self.t_grid, self.yaw)
        roll, pitch, dz = np.zeros_like(t), np.full_like(t, self.pitch0), np.zeros_like(t)
        ph = self.phase
        if self.mount == "legged":
            pitch = pitch + self.sway[0] * np.sin(2 * np.pi * self.gait * t + ph[0])
            roll = self.sway[1] * np.sin(np.pi * self.gait * t + ph[1])
            dz = self.bob * np.sin(2 * np.pi * self.gait * t + ph[2])
        elif self.mount == "handheld":
            amp, f = self.sweep
            yaw = yaw + amp * np.sin(2 * np.pi * f * t + ph[0])
            for t_start, angle, length in self.glances:  # sin^2 bump: out and back, peak rate angle * pi / length
                tau = np.clip((t - t_start) / length, 0.0, 1.0)
                yaw = yaw + angle * np.sin(np.pi * tau) ** 2
            roll = sum(a * np.sin(2 * np.pi * fr * t + p) for a, fr, p in self.roll_waves)
            pitch = pitch + sum(a * np.sin(2 * np.pi * fr * t + p) for a, fr, p in self.pitch_waves)
            dz = self.bob * np.sin(2 * np.pi * self.gait * t + ph[2])
        T = np.zeros(t.shape + (4, 4))
        T[..., :3, :3] = euler_to_matrix(roll, pitch, yaw)
        T[..., 0, 3], T[..., 1, 3] = x, y
        T[..., 2, 3] = self.floor(x, y) + self.height + dz
        T[..., 3, 3] = 1.0
        return T
