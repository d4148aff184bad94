"""Spinning multi-beam LiDAR model and the Embree ray caster behind it (no ROS).

Sensor frame (REP-103): x forward, y left, z up, origin at the optical centre. A sweep has
``columns`` firings; column ``c`` fires all beams at once at azimuth ``pi - c * step`` (the head spins
clockwise seen from above, starting and ending behind the vehicle, like a Velodyne) and at time
``c / columns / rate_hz`` seconds after the scan stamp (start of the sweep).
Beam (ring) 0 is the lowest beam.
"""

from __future__ import annotations

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
        """(columns, beams, 3) float64 unit ray directions in the sensor frame."""
        el = self.elevations()[None, :]
        az = self.azimuths()[:, None]
        ce = np.cos(el)
        return np.stack(np.broadcast_arrays(ce * np.cos(az), ce * np.sin(az), np.sin(el)), axis=-1)


class RayCaster:
    """Closest-hit ray casting against a static triangle mesh with Embree (via ``embreex``).

    The mesh is shifted by ``origin`` (a world point near the sensor) before it is handed to Embree,
    which works in float32; rays are shifted the same way, so world coordinates of any size keep
    millimetre precision.

    vertices: (V, 3) float64 world; faces: (F, 3) int; origin: (3,) float64 world.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray | None = None) -> None:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError as err:  # pragma: no cover - embreex is an install requirement
            raise SimulationError("the LiDAR simulator needs the 'embreex' package (pip install embreex)") from err
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, dtype=np.float64)
        self.num_faces = int(len(faces))
        self._scene = None
        if self.num_faces:
            self._scene = rtcore_scene.EmbreeScene()
            TriangleMesh(
                scene=self._scene,
                vertices=np.ascontiguousarray(vertices - self.origin, dtype=np.float32),
                indices=np.ascontiguousarray(faces, dtype=np.int32),
            )

    def cast(self, origins: np.ndarray, directions: np.ndarray, max_range: float):
        """Cast rays; returns (dist (N,) float32, face (N,) int32 (-1 = miss), normal (N, 3) float32).

        origins: (N, 3) float64 world; directions: (N, 3) unit vectors. ``dist`` is ``max_range``
        for misses; ``normal`` is the (unnormalised) geometric normal of the hit face.
        """
        n = len(origins)
        if self._scene is None or n == 0:
            return (np.full(n, max_range, np.float32), np.full(n, -1, np.int32), np.zeros((n, 3), np.float32))
        o = np.ascontiguousarray(origins - self.origin, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        out = self._scene.run(o, d, dists=np.full(n, max_range, np.float32), output=1)
        return out["tfar"], out["primID"].astype(np.int32), out["Ng"]
