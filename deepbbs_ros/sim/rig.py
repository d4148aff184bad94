"""Any sensor on any mount in any place: scans with ground truth (no ROS).

:func:`make_simulator` returns the road :class:`~deepbbs_ros.sim.simulator.DriveSimulator` itself for a
spinning sensor on a car on a road scene (so those drives stay exactly what they were), and a
:class:`RigSimulator` otherwise: a sensor (:data:`~deepbbs_ros.sim.patterns.SENSORS`) carried by a
mount (:data:`~deepbbs_ros.sim.mounts.MOUNTS`) through a place (a road scene, along its ego lane, or one
of :data:`~deepbbs_ros.sim.places.PLACES`, round its loop).

Timing and frames follow the drive simulator: frame ``k`` starts at ``k / rate_hz`` s, its stamp is
``STAMP0_NS + round(t_k * 1e9)``, ``Scan.T_world_lidar`` is the sensor's true pose at the stamp, every
ray is cast from the pose at its own firing time (``motion_distortion``), and ``compensate`` expresses
the points in the sensor frame at the stamp (the time field then goes). Raw scans carry their per-point
times in the field their driver uses (:func:`~deepbbs_ros.sim.patterns.driver_fields`). Road scenes
have no moving cars here.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.datasets.base import APOLLO_LIDAR_FRAME, Scan
from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.frames import Frames
from deepbbs_ros.sim.lidar import LidarConfig, RayCaster, lidar_sweep
from deepbbs_ros.sim.mounts import MOUNTS, MountTrajectory
from deepbbs_ros.sim.patterns import SolidStateConfig, driver_fields, make_sensor
from deepbbs_ros.sim.places import PLACES, build_place
from deepbbs_ros.sim.scene import ROAD_DZ, SCENES, World
from deepbbs_ros.sim.simulator import ANCHOR_STEP, S_START, DriveSimulator
from deepbbs_ros.sim.solid_state import pattern_sweep

ALL_PLACES = (*SCENES, *PLACES)


def make_simulator(place: str, seed: int, sensor: str | LidarConfig | SolidStateConfig = "hdl64",
                   mount: str = "car", **kw):
    """The simulator for ``sensor`` on ``mount`` in ``place``; ``kw``: frames, rate_hz, motion_distortion,
    compensate. A LidarConfig on a car on a road scene gives the unchanged :class:`DriveSimulator`."""
    lidar = make_sensor(sensor) if isinstance(sensor, str) else sensor
    if mount == "car" and place in SCENES and isinstance(lidar, LidarConfig):
        return DriveSimulator(place, seed, lidar, **kw)
    return RigSimulator(place, seed, lidar, mount, **kw)


class RigSimulator(Frames):
    """A reproducible recording of ``sensor`` carried by ``mount`` through ``place`` (see the module)."""

    def __init__(self, place: str, seed: int, sensor: LidarConfig | SolidStateConfig, mount: str, *,
                 frames: int = 100, rate_hz: float = 10.0, motion_distortion: bool = True,
                 compensate: bool = False) -> None:
        if place not in ALL_PLACES:
            raise SimulationError(f"unknown place {place!r}; choose one of {', '.join(ALL_PLACES)}")
        if mount not in MOUNTS:
            raise SimulationError(f"unknown mount {mount!r}; choose one of {', '.join(MOUNTS)}")
        if int(frames) < 1 or not 0.5 <= float(rate_hz) <= 50.0:
            raise SimulationError("frames must be >= 1 and rate_hz in [0.5, 50]")
        sensor.validate()
        self.scene, self.place, self.seed, self.mount = place, place, int(seed), mount
        self.lidar, self.frames, self.rate_hz = sensor, int(frames), float(rate_hz)
        self.period = 1.0 / self.rate_hz
        self.motion_distortion, self.compensate = bool(motion_distortion), bool(compensate)
        duration = self.frames * self.period + self.period
        self.world = None
        if place in SCENES:  # along the ego lane of a road scene
            length = S_START + 4.0 * (duration + 2.0) + sensor.max_range + ANCHOR_STEP + 150.0
            self.world = World(place, self.seed, length)
            s = np.arange(S_START, length - sensor.max_range - 60.0, 1.0)
            path = self.world.route.lateral(s, self.world.style.ego_offset)

            def floor(x, y):
                return self.world.terrain.height(x, y) + ROAD_DZ

            closed = False
        else:
            self.world = build_place(place, self.seed)
            path, floor, closed = self.world.path, self.world.floor_height, True
            self._caster = (RayCaster(self.world.vertices, self.world.faces), self.world.albedo)
        self.trajectory = MountTrajectory(mount, path, floor, self.seed, duration, closed=closed,
                                          sensor_height=sensor.mount_height, sensor_pitch_deg=sensor.mount_pitch_deg)
        self._casters: dict[tuple[int, int], tuple[RayCaster, np.ndarray]] = {}
        if isinstance(sensor, LidarConfig):
            self._ring_gain = np.random.default_rng([self.seed, 707]).uniform(0.85, 1.15, sensor.beams)
            self._col_time = np.arange(sensor.columns) * (self.period / sensor.columns)

    def T_world_lidar(self, t: np.ndarray | float) -> np.ndarray:
        return self.trajectory.poses(t)

    def _static(self, xy: np.ndarray) -> tuple[RayCaster, np.ndarray]:
        if self.place not in SCENES:
            return self._caster
        key = (int(xy[0] // ANCHOR_STEP), int(xy[1] // ANCHOR_STEP))
        if key not in self._casters:
            anchor = (np.asarray(key, dtype=np.float64) + 0.5) * ANCHOR_STEP
            v, f, alb = self.world.static_mesh(anchor, self.lidar.max_range + ANCHOR_STEP + 15.0)
            self._casters = {key: (RayCaster(v, f, np.array([anchor[0], anchor[1], 0.0])), alb)}
        return self._casters[key]

    def scan_at(self, frame: int) -> Scan:
        if not 0 <= int(frame) < self.frames:
            raise SimulationError(f"frame {frame} out of range [0, {self.frames})")
        frame = int(frame)
        t0 = frame * self.period
        T0 = self.T_world_lidar(t0)
        static = self._static(T0[:2, 3])
        rng = np.random.default_rng([self.seed, frame, 616])
        lid = self.lidar
        if isinstance(lid, SolidStateConfig):
            dirs, times, line = lid.pattern(t0, self.period)
            T_rays = self.T_world_lidar(t0 + times) if self.motion_distortion else \
                np.broadcast_to(T0, (len(times), 4, 4))
            pts, fields = pattern_sweep(lid, dirs, times, line, T_rays, static, rng)
        else:
            T_cols = self.T_world_lidar(t0 + self._col_time) if self.motion_distortion else \
                np.broadcast_to(T0, (lid.columns, 4, 4))
            pts, fields = lidar_sweep(lid, T_cols, static, rng, period=self.period, ring_gain=self._ring_gain)
        stamp = self.stamp_ns(frame)
        if self.compensate:
            fields = dict(fields)
            t = fields.pop("time").astype(np.float64)
            if self.motion_distortion:  # else every ray was cast from T0: nothing to undo
                T_rel = np.linalg.inv(T0) @ self.T_world_lidar(t0 + t)  # (N, 4, 4) T_lidar0_lidar(t)
                pts = (np.einsum("nij,nj->ni", T_rel[:, :3, :3], pts.astype(np.float64)) + T_rel[:, :3, 3])
                pts = pts.astype(np.float32)
        else:
            fields = driver_fields(lid.name, fields, stamp)
        return Scan(index=frame, stamp_ns=stamp, points=pts, fields=fields, frame_id=APOLLO_LIDAR_FRAME,
                    T_world_lidar=T0.copy())
