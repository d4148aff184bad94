"""A spinning multi-beam LiDAR's model (no ROS): :class:`LidarConfig` (beams, field of view, columns, ranges, noise,
mount, presets) and its (columns, beams) ray directions; sim/lidar.py's module docstring gives the sensor frame and
the firing order, its :func:`~deepbbs_ros.sim.lidar.lidar_sweep` casts them."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np

from deepbbs_ros.errors import SimulationError


def _hdl64_elevations() -> tuple[float, ...]:
    # HDL-64E: upper block 32 lasers at ~1/3 deg from +2.0, lower block 32 at ~1/2 deg down to -24.8.
    upper = np.linspace(2.0, 2.0 - 31 / 3, 32)
    lower = np.linspace(upper[-1] - 0.5, -24.8, 32)
    return tuple(float(e) for e in np.sort(np.concatenate([upper, lower])))


@dataclass
class LidarConfig:
    """A spinning LiDAR. Angles in degrees (names say so), distances in metres.

    elevations_deg: explicit beam elevations (ascending); empty = ``beams`` spread uniformly over
        [vfov_min_deg, vfov_max_deg].
    range_noise: Gaussian range noise sigma (m). dropout: probability that a return is lost.
    mount_height: height of the optical centre above the road (m); mount_pitch_deg: nose-down tilt
        of the sensor (positive tilts the x axis down).
    organized: Ouster-like output, points ordered ring-major (row by row) with a ``column`` field;
        otherwise Velodyne-like firing order (column-major, i.e. sorted by time).
    """

    beams: int = 64
    vfov_min_deg: float = -24.8
    vfov_max_deg: float = 2.0
    azimuth_step_deg: float = 0.18
    max_range: float = 120.0
    min_range: float = 0.9
    range_noise: float = 0.02
    dropout: float = 0.02
    mount_height: float = 1.9
    mount_pitch_deg: float = 0.0
    organized: bool = False
    elevations_deg: tuple[float, ...] = field(default_factory=tuple)
    name: str = "custom"

    @classmethod
    def hdl64(cls, **kw) -> LidarConfig:
        """Velodyne HDL-64E: 64 beams, -24.8..+2 deg, 0.18 deg azimuth (2000 columns), 120 m."""
        return replace(cls(name="hdl64", elevations_deg=_hdl64_elevations()), **kw)

    @classmethod
    def hdl32(cls, **kw) -> LidarConfig:
        """Velodyne HDL-32E: 32 beams, -30.67..+10.67 deg, 0.16 deg azimuth, 100 m."""
        return replace(
            cls(
                name="hdl32", beams=32, vfov_min_deg=-30.67, vfov_max_deg=10.67, azimuth_step_deg=0.16, max_range=100.0
            ),
            **kw,
        )

    @classmethod
    def vlp16(cls, **kw) -> LidarConfig:
        """Velodyne VLP-16: 16 beams, -15..+15 deg, 0.2 deg azimuth, 100 m, 3 cm noise."""
        return replace(
            cls(
                name="vlp16",
                beams=16,
                vfov_min_deg=-15.0,
                vfov_max_deg=15.0,
                azimuth_step_deg=0.2,
                max_range=100.0,
                range_noise=0.03,
            ),
            **kw,
        )

    @classmethod
    def ouster64(cls, **kw) -> LidarConfig:
        """Ouster OS1-64-like: 64 beams, -16.6..+16.6 deg, 1024 columns, organised output, 120 m."""
        return replace(
            cls(
                name="ouster64",
                beams=64,
                vfov_min_deg=-16.6,
                vfov_max_deg=16.6,
                azimuth_step_deg=360.0 / 1024,
                max_range=120.0,
                range_noise=0.015,
                organized=True,
            ),
            **kw,
        )

    @classmethod
    def preset(cls, name: str, **kw) -> LidarConfig:
        presets = {"hdl64": cls.hdl64, "hdl32": cls.hdl32, "vlp16": cls.vlp16, "ouster64": cls.ouster64}
        if name not in presets:
            raise SimulationError(f"unknown LiDAR preset {name!r}; choose one of {sorted(presets)}")
        return presets[name](**kw)

    # ---- derived quantities --------------------------------------------------------------------
    def validate(self) -> None:
        if self.beams < 1:
            raise SimulationError(f"lidar.beams must be >= 1, got {self.beams}")
        if self.elevations_deg and len(self.elevations_deg) != self.beams:
            raise SimulationError(f"lidar.elevations_deg has {len(self.elevations_deg)} values but beams={self.beams}")
        if not self.elevations_deg and not self.vfov_min_deg < self.vfov_max_deg:
            raise SimulationError("lidar.vfov_min_deg must be < vfov_max_deg")
        if not 0.01 <= self.azimuth_step_deg <= 45.0:
            raise SimulationError(f"lidar.azimuth_step_deg must be in [0.01, 45], got {self.azimuth_step_deg}")
        if not 0 <= self.min_range < self.max_range:
            raise SimulationError("lidar needs 0 <= min_range < max_range")
        if self.range_noise < 0 or not 0 <= self.dropout < 1:
            raise SimulationError("lidar needs range_noise >= 0 and 0 <= dropout < 1")

    @property
    def columns(self) -> int:
        return int(round(360.0 / self.azimuth_step_deg))

    def elevations(self) -> np.ndarray:
        """(beams,) float64 radians, ascending (ring 0 lowest)."""
        if self.elevations_deg:
            return np.deg2rad(np.sort(np.asarray(self.elevations_deg, dtype=np.float64)))
        if self.beams == 1:
            return np.deg2rad(np.array([0.5 * (self.vfov_min_deg + self.vfov_max_deg)]))
        return np.deg2rad(np.linspace(self.vfov_min_deg, self.vfov_max_deg, self.beams))

    def azimuths(self) -> np.ndarray:
        """(columns,) float64 radians: pi, pi - step, ... (clockwise from behind)."""
        return np.pi - np.arange(self.columns) * (2 * np.pi / self.columns)

    def directions(self) -> np.ndarray:
        """(columns, beams, 3) float64 unit ray directions in the sensor frame (read-only, cached)."""
        return _directions(tuple(self.elevations().tolist()), self.columns)


@functools.lru_cache(maxsize=8)
def _directions(elevations: tuple[float, ...], columns: int) -> np.ndarray:
    el = np.asarray(elevations)[None, :]
    az = (np.pi - np.arange(columns) * (2 * np.pi / columns))[:, None]
    ce = np.cos(el)
    d = np.stack(np.broadcast_arrays(ce * np.cos(az), ce * np.sin(az), np.sin(el)), axis=-1)
    d.setflags(write=False)
    return d
