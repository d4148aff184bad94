"""Synthetic structured scans with exact ground truth, for the node's tests and latency benchmark.

A fixed random "town" (ground plane, building walls, boxes, poles) is sampled on its surfaces; a scan
at sensor pose ``T_world_lidar`` is an independent random sample of the surfaces within
``max_range`` of the sensor, expressed in the sensor frame. It has no occlusion (not a LiDAR
simulation: :mod:`deepbbs_ros.sim` does that) but two scans of it overlap exactly, so any error of a
registration is the registration's. No ROS import.
"""

from __future__ import annotations

import numpy as np


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """(4, 4) float64 ``T`` with rotation ``yaw`` (rad) about z and translation (x, y, z) m."""
    T = np.eye(4)
    T[:3, :3] = _rot_z(yaw)
    T[:3, 3] = (x, y, z)
    return T


class SyntheticTown:
    """Surfaces of a random town around the origin, sampled on demand.

    Args:
        seed: layout seed.
        extent: half size of the square area, metres.
        mount_height: sensor height above the ground, metres (ground at ``z = -mount_height`` in a
            sensor frame at the world origin).
    """

    def __init__(self, seed: int = 0, extent: float = 120.0, mount_height: float = 1.9) -> None:
        rng = np.random.default_rng(seed)
        self.extent = extent
        self.ground_z = -mount_height
        # objects: (cx, cy, yaw, sx, sy, height); walls are long thin boxes, poles small squares
        objs = []
        for _ in range(70):  # buildings / walls, kept off the road along x (|y| > 8)
            cx, cy = rng.uniform(-extent, extent, 2)
            if abs(cy) < 8:
                cy = np.sign(cy or 1.0) * rng.uniform(8, 20)
            objs.append((cx, cy, rng.uniform(0, np.pi), rng.uniform(4, 25), rng.uniform(0.4, 10), rng.uniform(3, 15)))
        for _ in range(120):  # poles, boxes, cars
            cx, cy = rng.uniform(-extent, extent, 2)
            s = rng.uniform(0.2, 2.5)
            objs.append((cx, cy, rng.uniform(0, np.pi), s, s * rng.uniform(0.5, 2), rng.uniform(1, 6)))
        self.objects = np.asarray(objs)
        sides = self.objects[:, 3:5]
        h = self.objects[:, 5]
        self._area = 2 * (sides[:, 0] + sides[:, 1]) * h  # vertical faces only

    def _sample_world(self, n: int, center: np.ndarray, radius: float, rng: np.random.Generator) -> np.ndarray:
        near = np.linalg.norm(self.objects[:, :2] - center[:2], axis=1) < radius + 15
        objs, area = self.objects[near], self._area[near]
        n_ground = int(n * 0.45)
        n_obj = n - n_ground
        # ground: denser near the sensor, like a spinning LiDAR
        r = radius * np.sqrt(rng.uniform(0, 1, n_ground)) ** 1.5
        a = rng.uniform(0, 2 * np.pi, n_ground)
        ground = np.stack([center[0] + r * np.cos(a), center[1] + r * np.sin(a), np.full(n_ground, self.ground_z)], 1)
        if len(objs) == 0:
            return ground
        k = rng.choice(len(objs), n_obj, p=area / area.sum())
        o = objs[k]
        face = rng.integers(0, 4, n_obj)
        u = rng.uniform(-0.5, 0.5, n_obj)
        along = np.where(face < 2, o[:, 3], o[:, 4]) * u
        across = np.where(face < 2, o[:, 4], o[:, 3]) * 0.5 * np.where(face % 2 == 0, 1.0, -1.0)
        lx = np.where(face < 2, along, across)
        ly = np.where(face < 2, across, along)
        c, s = np.cos(o[:, 2]), np.sin(o[:, 2])
        x = o[:, 0] + c * lx - s * ly
        y = o[:, 1] + s * lx + c * ly
        z = self.ground_z + rng.uniform(0, 1, n_obj) * o[:, 5]
        return np.concatenate([ground, np.stack([x, y, z], 1)])

    def scan(
        self, T_world_lidar: np.ndarray, n_points: int = 120_000, *, seed: int = 0, max_range: float = 80.0,
        noise: float = 0.01,
    ) -> np.ndarray:
        """(n_points, 3) float32 points in the sensor frame of ``T_world_lidar`` (metres)."""
        rng = np.random.default_rng(seed)
        T = np.asarray(T_world_lidar, dtype=np.float64)
        pts = self._sample_world(int(n_points * 1.3) + 100, T[:3, 3], max_range, rng)
        local = (pts - T[:3, 3]) @ T[:3, :3]  # R^T (p - t)
        d = np.linalg.norm(local, axis=1)
        local = local[(d > 2.5) & (d < max_range)]
        if len(local) >= n_points:
            local = local[rng.choice(len(local), n_points, replace=False)]
        local = local + rng.normal(0, noise, local.shape)
        return local.astype(np.float32)
