"""One frame of a simulated drive cast (no ROS): :class:`DriveSweeps`, the ray-casting half of
sim/simulator.py's ``DriveSimulator`` (the static scene around the route rebuilt every :data:`ANCHOR_STEP` metres,
the moving cars, the sweep with or without motion distortion, the compensated sweep); the module docstring of
sim/simulator.py gives the frames' timing and the sweep's model."""

from __future__ import annotations

import time

import numpy as np

from deepbbs_ros.datasets.base import APOLLO_LIDAR_FRAME, Scan
from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.lidar import RayCaster, lidar_sweep
from deepbbs_ros.sim.sweep import compensate, rays_towards

ANCHOR_STEP = 40.0  # m of route length between rebuilds of the ray-casting scene


class DriveSweeps:
    """``scan_at(k)`` of a drive: a mixin of ``DriveSimulator``, which fills the world, the trajectory, the LiDAR
    and its timing (``period``, ``_col_time``, ``_ring_gain``), the casters' cache and ``timings_s``."""

    # ---- ray casting ------------------------------------------------------------------------------
    def _static_caster(self, t0: float) -> tuple[RayCaster, np.ndarray]:
        """The static scene around the route anchor for time t0 (rebuilt every ANCHOR_STEP metres).

        The anchor depends only on the frame's position, so random access and sequential access
        build identical scenes (bit-identical frames).
        """
        s = float(np.interp(t0, self.trajectory.t_grid, self.trajectory.s_grid))
        key = int(s // ANCHOR_STEP)
        if key not in self._casters:
            tb = time.perf_counter()
            anchor, _, _ = self.world.route.sample(key * ANCHOR_STEP)
            radius = self.lidar.max_range + ANCHOR_STEP + 15.0
            v, f, alb = self.world.static_mesh(anchor, radius)
            origin = np.array([np.round(anchor[0]), np.round(anchor[1]), 0.0])
            self._casters[key] = (RayCaster(v, f, origin), alb)
            while len(self._casters) > 3:
                self._casters.popitem(last=False)
            self.timings_s["build"] += time.perf_counter() - tb
        self._casters.move_to_end(key)
        return self._casters[key]

    def scan_at(self, frame: int) -> Scan:
        """Simulate frame ``frame`` (0-based): a :class:`~deepbbs_ros.datasets.base.Scan`."""
        if not 0 <= int(frame) < self.frames:
            raise SimulationError(f"frame {frame} out of range [0, {self.frames})")
        frame = int(frame)
        lid = self.lidar
        t0 = frame * self.period
        caster, albedo = self._static_caster(t0)
        ncol, nb = lid.columns, lid.beams
        if self.motion_distortion:
            T_cols = self.T_world_lidar(t0 + self._col_time)  # (C, 4, 4): pose at each firing
        else:
            T_cols = np.broadcast_to(self.T_world_lidar(t0), (ncol, 4, 4))
        T0 = T_cols[0].copy()
        dynamic = None
        mv, mf, ma = self.world.moving_mesh(t0 + 0.5 * self.period, T0[:2, 3], lid.max_range + 30.0,
                                             ego_xy=self.T_world_lidar(t0 + 0.5 * self.period)[:2, 3])
        if len(mf):  # moving cars, frozen at mid-sweep; only rays whose azimuth can reach them
            sel = rays_towards(lid, mv, T_cols[0], T_cols[-1], nb)
            dynamic = (RayCaster(mv, mf, caster.origin), ma, sel)
        rng = np.random.default_rng([self.seed, frame, 606])
        pts, fields = lidar_sweep(
            lid,
            T_cols,
            (caster, albedo),
            rng,
            period=self.period,
            dynamic=dynamic,
            ring_gain=self._ring_gain,
            timings=self.timings_s,
        )
        if self.compensate:
            pts, fields = compensate(pts, fields, T_cols, self.period, lid.columns)
        return Scan(
            index=frame,
            stamp_ns=self.stamp_ns(frame),
            points=pts,
            fields=fields,
            frame_id=APOLLO_LIDAR_FRAME,
            T_world_lidar=T0.copy(),
        )
