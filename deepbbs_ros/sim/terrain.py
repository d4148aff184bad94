"""The road scenes' ground: a height field with roadside relief, meshed in tiles (no ROS)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from deepbbs_ros.sim.geometry import strip

TILE = 40.0  # m, terrain tile edge
TILE_RES = 2.0  # m, terrain grid spacing
DITCH_AT, DITCH_HALF = 1.0, 1.2  # m beyond the corridor: the ditches' centre line and half width


class Terrain:
    """Height field g(x, y): long-wavelength sinusoids (200-600 m, slopes of a few %) everywhere, plus,
    away from the roads only, roadside relief: shorter hills (25-90 m wavelengths), embankments and
    cuttings (ground falling or rising with the distance from the road) and ditches just beside it.

    The relief is faded in from ``1 m`` beyond each road's edge (:meth:`attach_roads`), so every
    road corridor keeps the smooth long-wavelength surface the vehicle drives on. Roads of different
    widths meet at junctions: a point of one road can lie nearer another (narrower) road's centreline
    than its own, and that road's ditch must not cut into it, so the relief is zero wherever any road's
    corridor reaches (``_inside``), whichever centreline is nearest.
    """

    def __init__(self, rng: np.random.Generator, amp: float) -> None:
        k = 3
        self.amp = amp * rng.uniform(0.5, 1.0, k) / k
        lam = rng.uniform(200.0, 600.0, k)
        ang = rng.uniform(0, 2 * np.pi, k)
        self.w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / lam)[:, None]
        self.phi = rng.uniform(0, 2 * np.pi, k)
        self._tiles: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._roads: cKDTree | None = None

    def attach_roads(self, xy: np.ndarray, edge: np.ndarray, rng: np.random.Generator, hills: float,
                     bank: float, ditch: float) -> None:
        """Roadside relief beyond the road corridors: centreline samples ``xy`` (K, 2) with their
        edge distance ``edge`` (K,) (m from the centreline); ``hills``: amplitude (m) of the short
        hills, ``bank``: slope of embankments / cuttings, ``ditch``: ditch depth (m)."""
        self._roads, self._edge = cKDTree(xy), np.asarray(edge, dtype=np.float64)
        # one tree per edge distance (every road has one; roads sharing one can share a tree): the distance
        # beyond the nearest corridor is the smallest over the roads, not the nearest centreline's
        self._by_edge = [(cKDTree(xy[self._edge == w]), float(w)) for w in np.unique(self._edge)]
        k = 4
        self.h_amp = hills * rng.uniform(0.4, 1.0, k) / 2
        lam = rng.uniform(25.0, 90.0, k)
        ang = rng.uniform(0, 2 * np.pi, k)
        self.h_w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / lam)[:, None]
        self.h_phi = rng.uniform(0, 2 * np.pi, k)
        ang = rng.uniform(0, 2 * np.pi, 2)  # embankment / cutting: slowly varying sign and slope
        self.b_w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / rng.uniform(150, 400, 2))[:, None]
        self.b_phi, self.bank, self.ditch = rng.uniform(0, 2 * np.pi, 2), bank, ditch

    def _base(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        return (self.amp * np.sin(arg)).sum(-1)

    def _relief(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        if self._roads is None:
            return np.zeros(np.shape(x))
        d, i = self._roads.query(np.stack([x, y], -1).reshape(-1, 2))
        e = (d - self._edge[i]).reshape(np.shape(x)) - 1.0  # m beyond the corridor
        ramp = np.clip(e / 8.0, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)
        arg = x[..., None] * self.h_w[:, 0] + y[..., None] * self.h_w[:, 1] + self.h_phi
        hills = (self.h_amp * np.sin(arg)).sum(-1)
        b = np.sin(x[..., None] * self.b_w[:, 0] + y[..., None] * self.b_w[:, 1] + self.b_phi)
        bank = self.bank * np.clip(b[..., 0] * 1.6, -1, 1) * np.clip(e - 2.0, 0.0, 14.0)
        ditch = -self.ditch * (0.6 + 0.4 * b[..., 1]) * np.clip(1.0 - ((e - DITCH_AT) / DITCH_HALF) ** 2, 0.0, 1.0)
        relief = ramp * hills + bank + ditch
        inside = self._inside(np.stack([x, y], -1).reshape(-1, 2), d, e.reshape(-1)).reshape(np.shape(x))
        return np.where(inside, 0.0, relief)[()] if inside.any() else relief

    def _inside(self, q: np.ndarray, d: np.ndarray, e: np.ndarray) -> np.ndarray:
        """Which of the points ``q`` (N, 2) (``d``: distance to the nearest centreline, ``e``: beyond its corridor)
        a road's corridor reaches (up to the ditches' inner rim, ``DITCH_AT - DITCH_HALF``) while ``e`` puts them
        beyond it: the points of a wide road nearer a narrower road's centreline, beside a junction. Elsewhere ``e``
        is already the smallest over the roads."""
        rim = DITCH_AT - DITCH_HALF
        out = np.zeros(len(q), bool)
        # only points beyond the nearest corridor yet within the widest one's reach can be inside another
        todo = np.flatnonzero((e > rim) & (d <= self._by_edge[-1][1] + 1.0 + rim))
        if len(self._by_edge) < 2 or not len(todo):
            return out
        e_min = np.min([tree.query(q[todo])[0] - w for tree, w in self._by_edge], axis=0) - 1.0
        out[todo] = (e_min <= rim) & (e[todo] - e_min > 1e-6)
        return out

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        return self._base(x, y) + self._relief(x, y)

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(dg/dx, dg/dy); the roadside relief by central differences (it is zero on the roads)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        c = self.amp * np.cos(arg)
        gx, gy = (c * self.w[:, 0]).sum(-1), (c * self.w[:, 1]).sum(-1)
        if self._roads is not None:
            h = 0.05
            gx = gx + (self._relief(x + h, y) - self._relief(x - h, y)) / (2 * h)
            gy = gy + (self._relief(x, y + h) - self._relief(x, y - h)) / (2 * h)
        return gx, gy

    def tile(self, ix: int, iy: int) -> tuple[np.ndarray, np.ndarray]:
        """Mesh of terrain tile (ix, iy) covering [ix*TILE, (ix+1)*TILE] x [iy*TILE, (iy+1)*TILE]."""
        key = (ix, iy)
        if key not in self._tiles:
            n = int(round(TILE / TILE_RES)) + 1
            gx, gy = np.meshgrid(
                ix * TILE + np.arange(n) * TILE_RES, iy * TILE + np.arange(n) * TILE_RES, indexing="ij"
            )
            self._tiles[key] = strip(np.stack([gx, gy, self.height(gx, gy)], -1))
        return self._tiles[key]

