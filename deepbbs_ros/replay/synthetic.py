"""The tiny structured point world for tests and benchmarks when no recording is at hand (the node's
tests, the replay and baseline tests; the LiDAR simulator :mod:`deepbbs_ros.sim` is the realistic one).

Not a LiDAR simulator: the world is a fixed random sample of surface points along a road on the x axis
(ground at z = 0, façades with gaps and side walls, boxes, poles); each "scan" keeps the world points
within range of the sensor, subsamples them (a random fraction, or a fixed count), adds noise and
expresses them in the sensor frame. There is no occlusion, so two scans overlap exactly and any error
of a registration is the registration's. Good enough to pin transform directions and recover known
motions in milliseconds. No ROS import.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.datasets.base import Scan

MOUNT_HEIGHT = 1.9  # m; sensor height above the road in :func:`drive_poses` (put it in hand-made poses too)


def pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """(4, 4) float64 ``T`` with rotation ``yaw`` (rad) about z and translation (x, y, z) m."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, z)
    return T


def _plane(rng: np.random.Generator, n: int, origin, u, v, size_u: float, size_v: float) -> np.ndarray:
    a = rng.uniform(0, size_u, n)[:, None]
    b = rng.uniform(0, size_v, n)[:, None]
    return np.asarray(origin) + a * np.asarray(u) + b * np.asarray(v)


def structured_world(seed: int = 0, length: float = 260.0, density: float = 1.0) -> np.ndarray:
    """World points (P, 3) float64 along a road on the x axis from x = -30 to ``length``.

    Ground at z = 0, façades at y = +-9 with gaps, random boxes and poles on both sides.
    """
    rng = np.random.default_rng(seed)
    d = density
    parts = [_plane(rng, int(30000 * d), (-30, -25, 0), (1, 0, 0), (0, 1, 0), length + 30, 50)]
    x = -30.0
    while x < length:  # façade blocks with gaps, both sides, varying set-back
        w = rng.uniform(8, 25)
        for side in (-1, 1):
            y = side * rng.uniform(9, 14)
            h = rng.uniform(4, 12)
            parts.append(_plane(rng, int(w * h * 3 * d), (x, y, 0), (1, 0, 0), (0, 0, 1), w, h))
            # a side wall gives the block some depth (x-constraint)
            parts.append(_plane(rng, int(5 * h * 3 * d), (x, y, 0), (0, side, 0), (0, 0, 1), 5, h))
        x += w + rng.uniform(2, 8)
    for _ in range(int(length / 6)):  # boxes (cars, kiosks) and poles
        cx, cy = rng.uniform(-30, length), rng.choice([-1, 1]) * rng.uniform(4, 8)
        sx, sy, sz = rng.uniform(1.5, 4.5), rng.uniform(1.5, 2.5), rng.uniform(1.2, 2.5)
        for face in range(4):
            if face < 2:
                o = (cx + (sx if face else 0), cy, 0)
                parts.append(_plane(rng, int(sy * sz * 20 * d), o, (0, 1, 0), (0, 0, 1), sy, sz))
            else:
                o = (cx, cy + (sy if face == 3 else 0), 0)
                parts.append(_plane(rng, int(sx * sz * 20 * d), o, (1, 0, 0), (0, 0, 1), sx, sz))
        px, py = rng.uniform(-30, length), rng.choice([-1, 1]) * rng.uniform(5, 8)
        ang = rng.uniform(0, 2 * np.pi, int(200 * d))
        hz = rng.uniform(0, 6, ang.size)
        parts.append(np.stack([px + 0.15 * np.cos(ang), py + 0.15 * np.sin(ang), hz], 1))
    return np.concatenate(parts, 0)


def drive_poses(frames: int, speed: float = 8.0, yaw_rate_deg: float = 1.0, rate_hz: float = 10.0,
                mount_height: float = MOUNT_HEIGHT) -> np.ndarray:
    """(F, 4, 4) float64 ``T_world_lidar`` of a gently curving drive at ``speed`` m/s (starts at the origin)."""
    dt = 1.0 / rate_hz
    poses = np.tile(np.eye(4), (frames, 1, 1))
    x = y = yaw = 0.0
    for k in range(frames):
        poses[k] = pose(x, y, mount_height, yaw)
        x += speed * dt * np.cos(yaw)
        y += speed * dt * np.sin(yaw)
        yaw += np.radians(yaw_rate_deg) * dt * (1.0 + np.sin(0.3 * k * dt))  # yaw rate in [0, 2 x] deg/s
    return poses


def scan_at(world: np.ndarray, T_world_lidar: np.ndarray, rng: np.random.Generator, *,
            max_range: float = 60.0, keep: float = 0.6, noise: float = 0.02,
            n_points: int | None = None) -> np.ndarray:
    """Points of ``world`` within ``max_range`` of the sensor at ``T_world_lidar``, a random ``keep``
    fraction of them (or, with ``n_points``, a random subset of exactly that many, all of them when
    fewer are in range), in the sensor frame with Gaussian noise ``noise`` m: (N, 3) float32."""
    p = world[np.linalg.norm(world[:, :2] - T_world_lidar[:2, 3], axis=1) < max_range]
    if n_points is None:
        p = p[rng.random(p.shape[0]) < keep]
    elif p.shape[0] > n_points:
        p = p[rng.choice(p.shape[0], n_points, replace=False)]
    R, t = T_world_lidar[:3, :3], T_world_lidar[:3, 3]
    local = (p - t) @ R  # R^T (p - t)
    local += rng.normal(0, noise, local.shape)
    return local.astype(np.float32)


def synthetic_drive(frames: int = 20, seed: int = 0, *, speed: float = 8.0, rate_hz: float = 10.0,
                    max_range: float = 60.0, keep: float = 0.6, frame_id: str = "velodyne64",
                    motion_distortion: bool = False,
                    t0_ns: int = 1_700_000_000_000_000_000) -> list[Scan]:
    """``frames`` scans of :func:`structured_world` along :func:`drive_poses`, with ground truth
    (``T_world_lidar`` at the stamp) and an ``intensity`` field.

    With ``motion_distortion`` every point is measured at its own time ``t`` in ``[0, 1/rate_hz)``
    (by azimuth, as a spinning sensor sweeps) from the sensor pose at ``stamp + t`` (linear motion
    towards the next pose), and the scan carries that ``time`` field (s since the stamp)."""
    rng = np.random.default_rng(seed + 1)
    length = speed * frames / rate_hz + max_range + 10
    world = structured_world(seed, length=length)
    poses = drive_poses(frames + 1, speed=speed, rate_hz=rate_hz)
    out = []
    for k in range(frames):
        T = poses[k]
        pts = scan_at(world, T, rng, max_range=max_range, keep=keep)
        fields = {"intensity": rng.uniform(0, 1, pts.shape[0]).astype(np.float32)}
        if motion_distortion:
            from scipy.spatial.transform import Rotation, Slerp

            frac = (np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi)  # sweep fraction by azimuth
            world_pts = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
            slerp = Slerp([0.0, 1.0], Rotation.from_matrix(poses[k : k + 2, :3, :3]))
            R_t = slerp(frac).as_matrix()  # (N, 3, 3) sensor orientation at each point's time
            t_t = T[:3, 3] + frac[:, None] * (poses[k + 1, :3, 3] - T[:3, 3])
            pts = np.einsum("nji,nj->ni", R_t, world_pts - t_t).astype(np.float32)
            fields["time"] = (frac / rate_hz).astype(np.float32)
        out.append(Scan(index=k, stamp_ns=t0_ns + int(k * 1e9 / rate_hz), points=pts,
                        fields=fields, frame_id=frame_id, T_world_lidar=T))
    return out
