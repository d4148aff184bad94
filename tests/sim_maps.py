"""Maps for the localization tests from a simulated drive (shared helper, not a test)."""

from __future__ import annotations

import numpy as np


def world_points(sim, frames, radius: float | None = None) -> np.ndarray:
    """(N, 3) the scans of ``sim`` (a ``DriveSimulator``) at ``frames`` in the world frame at their true poses, each
    cut to the points within ``radius`` m of its sensor when given."""
    parts = []
    for k in frames:
        s = sim.scan_at(k)
        p = s.points if radius is None else s.points[np.linalg.norm(s.points, axis=1) < radius]
        parts.append(p @ s.T_world_lidar[:3, :3].T + s.T_world_lidar[:3, 3])
    return np.concatenate(parts)
