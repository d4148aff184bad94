"""Ego-vehicle trajectory along a :class:`~deepbbs_ros.sim.scene.Route` (no ROS).

Speed profile: cruise speed of the scene, slowed in curves to ``sqrt(a_lat / |kappa|)``, full stops
(with a dwell time) at some intersections, acceleration limited to 1.5 m/s^2 and braking to
2.5 m/s^2. The vehicle drives in its lane (``Style.ego_offset`` left of the centreline), on the
road surface; pitch and roll follow the terrain slope plus the body's reaction to acceleration and
cornering plus a small vibration.

Base frame (``T_world_base``): on the road surface under the LiDAR, x forward, z up.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.scene import ROAD_DZ, World

A_ACC, A_BRAKE = 1.5, 2.5  # m/s^2
DT = 0.01  # s, resolution of the precomputed time grid


def euler_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(..., 3, 3) R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


class Trajectory:
    """Time-parametrised ego poses for ``duration`` seconds starting at arc length ``s_start``.

    world: the :class:`World` (route, terrain, stops); seed: randomness of speed and vibration.
    lane_offset: the lane driven, metres left of the centreline in the route's direction (None: the scene's
    ego lane, or its mirror on the other side when ``reverse``). reverse: drive against the route's direction
    (towards smaller arc length, from ``s_start``), e.g. the opposite lane of the road another drive took.
    """

    def __init__(self, world: World, seed: int, duration: float, s_start: float = 80.0, *,
                 lane_offset: float | None = None, reverse: bool = False) -> None:
        self.world = world
        st = world.style
        rng = np.random.default_rng([int(seed), 505])
        route = world.route
        ds = 0.1
        self.reverse = bool(reverse)
        if self.reverse:
            s = s_start - np.arange(0.0, s_start - 1.0, ds)
        else:
            s = np.arange(s_start, route.length - 1.0, ds)
        _, _, kap = route.sample(s)
        v_cruise = rng.uniform(*st.v_cruise)
        # slow cruise variations (traffic), curve speed limits
        wob = 1.0 + 0.08 * np.sin(2 * np.pi * s / rng.uniform(300, 700) + rng.uniform(0, 6.3))
        v_lim = np.minimum(v_cruise * wob, np.sqrt(st.a_lat / np.maximum(np.abs(kap), 1e-6)))
        v_lim = np.minimum(v_lim, 20.0)
        stop_idx = []
        for s_stop, dwell in world.stops:
            i = int(round((s_start - s_stop if self.reverse else s_stop - s_start) / ds))
            if 0 < i < len(s):
                v_lim[i] = 0.0
                stop_idx.append((i, dwell))
        if rng.uniform() < st.start_stopped_prob:
            v_lim[0] = 0.0
        # forward (acceleration) and backward (braking) passes: v^2 <= v_prev^2 + 2 a ds
        v = v_lim.copy()
        for i in range(1, len(v)):
            v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * A_ACC * ds))
        for i in range(len(v) - 2, -1, -1):
            v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * A_BRAKE * ds))
        dt_seg = ds / np.maximum(0.5 * (v[1:] + v[:-1]), 1e-3)
        t_of_s = np.concatenate([[0.0], np.cumsum(dt_seg)])
        for i, dwell in sorted(stop_idx, reverse=True):  # hold still at each stop
            t_of_s = np.insert(t_of_s, i + 1, t_of_s[i] + dwell)
            t_of_s[i + 2 :] += dwell
            s = np.insert(s, i + 1, s[i])
        if t_of_s[-1] < duration + 1.0:
            from deepbbs_ros.errors import SimulationError

            raise SimulationError(f"route too short for a {duration:.1f} s drive (internal: lengthen the world)")
        self.t_grid = np.arange(0.0, duration + 1.0, DT)
        self.s_grid = np.interp(self.t_grid, t_of_s, s)
        self.v_grid = np.gradient(self.s_grid, DT)
        self.a_grid = np.convolve(np.gradient(self.v_grid, DT), np.ones(25) / 25, mode="same")
        self.ego_offset = (-st.ego_offset if self.reverse else st.ego_offset) if lane_offset is None \
            else float(lane_offset)
        self.duration = duration
        # vibration: a few small sinusoids per axis (rad)
        self._vib = [(rng.uniform(0.0005, 0.0015), rng.uniform(0.5, 3.0), rng.uniform(0, 6.3)) for _ in range(6)]

    def speed(self, t: np.ndarray | float) -> np.ndarray:
        """Forward speed (m/s) at time ``t`` (s)."""
        return np.interp(t, self.t_grid, self.v_grid)

    def poses(self, t: np.ndarray | float) -> np.ndarray:
        """(..., 4, 4) float64 ``T_world_base`` at times ``t`` (s since the start of the drive)."""
        t = np.asarray(t, dtype=np.float64)
        route, terrain = self.world.route, self.world.terrain
        s = np.interp(t, self.t_grid, self.s_grid)
        v = np.interp(t, self.t_grid, self.v_grid)
        a = np.interp(t, self.t_grid, self.a_grid)
        _, yaw, kap = route.sample(s)
        if self.reverse:  # facing back along the route: heading turned round, curvature mirrored
            yaw, kap = yaw + np.pi, -kap
        xy = route.lateral(s, self.ego_offset)
        z = terrain.height(xy[..., 0], xy[..., 1]) + ROAD_DZ
        gx, gy = terrain.gradient(xy[..., 0], xy[..., 1])
        fwd = gx * np.cos(yaw) + gy * np.sin(yaw)
        left = -gx * np.sin(yaw) + gy * np.cos(yaw)
        vib = [amp * np.sin(2 * np.pi * f * t + ph) for amp, f, ph in self._vib]
        pitch = -np.arctan(fwd) - 0.004 * a + vib[0] + vib[1] + vib[2]
        roll = np.arctan(left) + 0.005 * v * v * kap + vib[3] + vib[4] + vib[5]
        T = np.zeros(t.shape + (4, 4))
        T[..., :3, :3] = euler_to_matrix(roll, pitch, yaw)
        T[..., 0, 3], T[..., 1, 3], T[..., 2, 3] = xy[..., 0], xy[..., 1], z
        T[..., 3, 3] = 1.0
        return T
