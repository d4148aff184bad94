"""Spinning multi-beam LiDAR model, cast by the Embree ray caster (sim/raycast.py) behind it (no ROS).

Sensor frame (REP-103): x forward, y left, z up, origin at the optical centre. A sweep has
``columns`` firings; column ``c`` fires all beams at once at azimuth ``pi - c * step`` (the head spins
clockwise seen from above, starting and ending behind the vehicle, like a Velodyne) and at time
``c / columns / rate_hz`` seconds after the scan stamp (start of the sweep).
Beam (ring) 0 is the lowest beam. The sensor's model: sim/lidar_config.py (:class:`LidarConfig`, imported from here
too); here the sweep cast (:func:`lidar_sweep`).
"""

from __future__ import annotations

import time

import numpy as np

from deepbbs_ros.sim.lidar_config import LidarConfig, _directions, _hdl64_elevations  # noqa: F401  (re-exported)
from deepbbs_ros.sim.raycast import RayCaster


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
