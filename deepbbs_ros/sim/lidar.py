"""Spinning multi-beam LiDAR model, cast by the Embree ray caster (sim/raycast.py) behind it (no ROS).

Sensor frame (REP-103): x forward, y left, z up, origin at the optical centre. A sweep has
``columns`` firings; column ``c`` fires all beams at once at azimuth ``pi - c * step`` (the head spins
clockwise seen from above, starting and ending behind the vehicle, like a Velodyne) and at time
``c / columns / rate_hz`` seconds after the scan stamp (start of the sweep).
Beam (ring) 0 is the lowest beam.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace

import numpy as np

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.raycast import RayCaster


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


def lidar_sweep(
    lidar: LidarConfig,
    T_cols: np.ndarray,
    static: tuple[RayCaster, np.ndarray],
    rng: np.random.Generator,
    *,
    period: float = 0.1,
    dynamic: tuple[RayCaster, np.ndarray, np.ndarray] | None = None,
    ring_gain: np.ndarray | None = None,
    timings: dict[str, float] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """One sweep: cast every (column, beam) ray, then add noise, dropouts and intensity.

    T_cols: (columns, 4, 4) float64 ``T_world_lidar`` at each column's firing time (all equal for
        an undistorted scan); static: (caster, albedo (F,) float32 per face);
    dynamic: optional (caster, albedo, ray indices (K,) int) cast only for those rays;
    ring_gain: (beams,) intensity gain per laser. rng draws noise and dropouts.

    Returns points (N, 3) float32 in the sensor frame at each point's firing time (distance along
    the beam direction) and fields ``intensity`` float32, ``time`` float32 (s since the sweep
    start), ``ring`` uint16, plus ``column`` uint16 when ``lidar.organized``.
    """
    t_start = time.perf_counter()
    dirs = lidar.directions()
    ncol, nb = dirs.shape[:2]
    n = ncol * nb
    d_world = np.matmul(dirs, T_cols[:, :3, :3].transpose(0, 2, 1)).reshape(-1, 3)
    o_world = np.broadcast_to(T_cols[:, None, :3, 3], (ncol, nb, 3)).reshape(-1, 3)
    caster, albedo = static
    dist, face, normal = caster.cast(o_world, d_world, lidar.max_range)
    alb = np.where(face >= 0, albedo[np.maximum(face, 0)], 0.0).astype(np.float32)
    if dynamic is not None and len(dynamic[2]):
        dcaster, dalb, sel = dynamic
        d2, f2, n2 = dcaster.cast(o_world[sel], d_world[sel], lidar.max_range)
        closer = (f2 >= 0) & (d2 < dist[sel])
        hit = sel[closer]
        dist[hit], face[hit], normal[hit] = d2[closer], f2[closer], n2[closer]
        alb[hit] = dalb[f2[closer]]
    t_cast = time.perf_counter()

    # noise, dropouts (more at grazing incidence and on dark far surfaces), intensity
    nx, ny, nz = normal[:, 0], normal[:, 1], normal[:, 2]
    dot = nx * d_world[:, 0] + ny * d_world[:, 1] + nz * d_world[:, 2]
    cos_inc = (np.abs(dot) / np.maximum(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-12)).astype(np.float32)
    r = dist + np.float32(lidar.range_noise) * rng.standard_normal(n, dtype=np.float32)
    drop_p = lidar.dropout + 0.5 * (cos_inc < 0.05) + 0.3 * (alb < 0.12) * (dist > 0.6 * lidar.max_range)
    keep = rng.random(n, dtype=np.float32) >= drop_p
    valid = (face >= 0) & (r >= lidar.min_range) & (r < lidar.max_range) & keep
    ring = np.broadcast_to(np.arange(nb, dtype=np.uint16), (ncol, nb)).reshape(-1)
    col = np.broadcast_to(np.arange(ncol, dtype=np.uint16)[:, None], (ncol, nb)).reshape(-1)
    gain = np.ones(nb, np.float32) if ring_gain is None else np.asarray(ring_gain, np.float32)
    speckle = 1.0 + 0.05 * rng.standard_normal(n, dtype=np.float32)
    inten = np.clip(255.0 * alb * (0.25 + 0.75 * cos_inc) * gain[ring] * speckle, 0.0, 255.0).astype(np.float32)
    if lidar.organized:  # ring-major order, like an image row by row
        order = np.arange(n).reshape(ncol, nb).T.reshape(-1)
        order = order[valid[order]]
    else:  # firing order: column by column
        order = np.flatnonzero(valid)
    pts = (r[order, None] * dirs.reshape(-1, 3)[order]).astype(np.float32)
    col_time = (np.arange(ncol) * (period / ncol)).astype(np.float32)
    fields = {"intensity": inten[order], "time": col_time[col[order]], "ring": ring[order].copy()}
    if lidar.organized:
        fields["column"] = col[order].copy()
    if timings is not None:
        timings["cast"] = timings.get("cast", 0.0) + t_cast - t_start
        timings["post"] = timings.get("post", 0.0) + time.perf_counter() - t_cast
    return pts, fields
