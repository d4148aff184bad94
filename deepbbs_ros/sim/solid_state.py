"""Ray casting of a non-repetitive (Livox) scan pattern (no ROS).

The same return model as :func:`~deepbbs_ros.sim.lidar.lidar_sweep` (Gaussian range noise, dropouts,
more of them at grazing incidence and on dark far surfaces, intensity from albedo and incidence), for
rays that each have their own direction and firing time instead of a (column, beam) grid.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.lidar import RayCaster
from deepbbs_ros.sim.patterns import SolidStateConfig


def pattern_sweep(
    cfg: SolidStateConfig,
    dirs: np.ndarray,
    times: np.ndarray,
    line: np.ndarray,
    T_rays: np.ndarray,
    static: tuple[RayCaster, np.ndarray],
    rng: np.random.Generator,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Cast one frame of a solid-state pattern.

    dirs: (N, 3) unit directions in the sensor frame; times: (N,) s since the frame stamp; line: (N,)
    uint8 laser line; T_rays: (N, 4, 4) ``T_world_lidar`` at each ray's firing time (all equal for an
    instantaneous scan); static: (caster, albedo per face). Returns points (N', 3) float32 in the sensor
    frame at each point's firing time, in firing order, and fields ``intensity`` float32, ``time`` float32
    (s since the stamp) and ``line`` uint8.
    """
    n = len(dirs)
    d_world = np.einsum("nij,nj->ni", T_rays[:, :3, :3], dirs)
    caster, albedo = static
    dist, face, normal = caster.cast(T_rays[:, :3, 3], d_world, cfg.max_range)
    alb = np.where(face >= 0, albedo[np.maximum(face, 0)], 0.0).astype(np.float32)
    nrm = np.maximum(np.linalg.norm(normal, axis=1), 1e-12)
    cos_inc = (np.abs(np.einsum("ni,ni->n", normal, d_world)) / nrm).astype(np.float32)
    r = dist + np.float32(cfg.range_noise) * rng.standard_normal(n, dtype=np.float32)
    drop_p = cfg.dropout + 0.5 * (cos_inc < 0.05) + 0.3 * (alb < 0.12) * (dist > 0.6 * cfg.max_range)
    keep = rng.random(n, dtype=np.float32) >= drop_p
    valid = (face >= 0) & (r >= cfg.min_range) & (r < cfg.max_range) & keep
    speckle = 1.0 + 0.05 * rng.standard_normal(n, dtype=np.float32)
    inten = np.clip(255.0 * alb * (0.25 + 0.75 * cos_inc) * speckle, 0.0, 255.0).astype(np.float32)
    idx = np.flatnonzero(valid)
    pts = (r[idx, None] * dirs[idx]).astype(np.float32)
    fields = {"intensity": inten[idx], "time": times[idx].astype(np.float32), "line": line[idx].astype(np.uint8)}
    return pts, fields


def coverage(dirs: np.ndarray, cell_deg: float = 1.0) -> int:
    """Number of ``cell_deg`` x ``cell_deg`` (azimuth x elevation) cells hit by the unit directions ``dirs``."""
    az = np.degrees(np.arctan2(dirs[:, 1], dirs[:, 0]))
    el = np.degrees(np.arcsin(np.clip(dirs[:, 2], -1.0, 1.0)))
    cells = np.floor(az / cell_deg).astype(np.int64) * 100_000 + np.floor(el / cell_deg).astype(np.int64)
    return int(len(np.unique(cells)))
