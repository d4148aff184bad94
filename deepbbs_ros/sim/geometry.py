"""Small triangle-mesh primitives for procedural scenes (numpy only, float64 world coordinates).

Every primitive returns ``(vertices (V, 3) float64, faces (F, 3) int64)``; :class:`MeshBuilder`
concatenates them with a per-triangle albedo (reflectivity in [0, 1], used for LiDAR intensity).
Faces are wound counter-clockwise seen from outside, but the ray caster does not rely on it.
"""

from __future__ import annotations

import functools

import numpy as np

_BOX_CORNERS = np.array(
    [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]],
    dtype=np.float64,
)
_BOX_FACES = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],  # bottom
        [4, 5, 6],
        [4, 6, 7],  # top
        [0, 1, 5],
        [0, 5, 4],  # -y
        [1, 2, 6],
        [1, 6, 5],  # +x
        [2, 3, 7],
        [2, 7, 6],  # +y
        [3, 0, 4],
        [3, 4, 7],  # -x
    ],
    dtype=np.int64,
)


def rot_z(yaw: float) -> np.ndarray:
    """(3, 3) rotation about +z by ``yaw`` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def box(center_base: np.ndarray, size: tuple[float, float, float], yaw: float = 0.0):
    """Oriented box standing on ``center_base`` (x, y, z of the bottom face centre).

    size: (length along the box x axis, width, height) in metres; yaw: heading of the box x axis.
    """
    half = np.array([size[0] / 2, size[1] / 2, size[2]])
    v = (_BOX_CORNERS * half) @ rot_z(yaw).T + np.asarray(center_base, dtype=np.float64)
    return v, _BOX_FACES.copy()


def cylinder(center_base: np.ndarray, radius: float, height: float, sides: int = 6):
    """Vertical prism with ``sides`` faces (open bottom, closed top) standing on ``center_base``."""
    a = np.arange(sides) * (2 * np.pi / sides)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(sides)], axis=1)
    v = np.concatenate([ring, ring + [0, 0, height], [[0, 0, height]]]) + np.asarray(center_base, dtype=np.float64)
    i = np.arange(sides)
    j = (i + 1) % sides
    side = np.concatenate([np.stack([i, j, j + sides], 1), np.stack([i, j + sides, i + sides], 1)])
    top = np.stack([i + sides, j + sides, np.full(sides, 2 * sides)], 1)
    return v, np.concatenate([side, top]).astype(np.int64)


@functools.lru_cache(maxsize=1)
def _icosphere() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=1)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def blob(center: np.ndarray, radii: tuple[float, float, float], rng: np.random.Generator, roughness: float = 0.25):
    """Irregular closed blob (tree crown, bush): an icosphere (80 faces) with radial jitter.

    radii: semi-axes (x, y, z) in metres; roughness: relative radial jitter (uniform +-).
    """
    v, f = _icosphere()
    jitter = 1.0 + rng.uniform(-roughness, roughness, size=(len(v), 1))
    return v * jitter * np.asarray(radii) + np.asarray(center, dtype=np.float64), f.copy()


_OCTA_V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
_OCTA_F = np.array(
    [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]], dtype=np.int64
)


def clusters(center: np.ndarray, radii: tuple[float, float, float], rng: np.random.Generator, n: int, size: float):
    """Porous foliage (tree crown, bush, hedge): ``n`` small octahedra (8 faces each, jittered
    semi-axes around ``size`` metres) scattered through the ellipsoid with semi-axes ``radii``.

    Rays pass through the gaps between clusters, so a crown returns points from its inside and from
    what lies behind it, as real foliage does.
    """
    u = rng.normal(size=(n, 3))
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-9)
    pos = u * (rng.uniform(0.0, 1.0, (n, 1)) ** (1 / 3)) * np.asarray(radii) + np.asarray(center, dtype=np.float64)
    half = size * rng.uniform(0.5, 1.5, (n, 1, 3))
    v = (_OCTA_V[None] * half + pos[:, None, :]).reshape(-1, 3)
    f = (_OCTA_F[None] + 6 * np.arange(n)[:, None, None]).reshape(-1, 3)
    return v, f


def strip(points: np.ndarray):
    """Triangle strip between rows of points: ``points`` (K, R, 3), K samples along a path, R rows
    across it; returns the (K-1)(R-1) quads as triangles."""
    k, r = points.shape[:2]
    j, i = np.meshgrid(np.arange(k - 1), np.arange(r - 1), indexing="ij")
    a = (j * r + i).ravel()
    f = np.concatenate([np.stack([a, a + r, a + r + 1], 1), np.stack([a, a + r + 1, a + 1], 1)])
    return np.asarray(points, dtype=np.float64).reshape(-1, 3), f.astype(np.int64)


class MeshBuilder:
    """Accumulates primitives into one mesh with a per-triangle albedo."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._a: list[np.ndarray] = []
        self._nv = 0

    def add(self, mesh: tuple[np.ndarray, np.ndarray], albedo: float | np.ndarray) -> None:
        v, f = mesh
        self._v.append(v)
        self._f.append(f + self._nv)
        self._a.append(np.broadcast_to(np.asarray(albedo, dtype=np.float32), (len(f),)))
        self._nv += len(v)

    def __len__(self) -> int:
        return len(self._f)

    def build(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """-> vertices (V, 3) float64, faces (F, 3) int64, albedo (F,) float32."""
        if not self._f:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.float32)
        return np.concatenate(self._v), np.concatenate(self._f), np.concatenate(self._a).astype(np.float32)
