"""The place descriptor of global localization (no ROS): Scan Context from a height grid.

A :class:`_HeightGrid` holds, per ``cell`` m square, the highest point above the local ground; a
:class:`_PolarTemplate` reads it into a ring x sector descriptor about any position (the map's places, the scan's
sensor and the points around it); :func:`_match` / :func:`_match_many` compare a scan's descriptor with every
place's at every column shift (a circular correlation by FFT: the best shift is the scan's yaw), the places' half
(:func:`_spectra`) computed once per map. Used by :class:`~deepbbs_ros.core.localization.MapLocalizer`.
"""

from __future__ import annotations

import numpy as np

GROUND_WINDOW = 5  # cells; the local ground of a cell is the lowest point within this window around it


def levelling(plane: np.ndarray | None, band: float, radius: float) -> np.ndarray | None:
    """The rotation (3, 3) that turns a scan's fitted ground plane ``[a, b, c, d]`` (sensor frame, unit normal) level,
    or None when its tilt is within what the fit itself can tell from level: ``atan(band / radius)``, the fit's inlier
    band (m) across its seed radius (m). The descriptor assumes an upright sensor; a rolled or pitched one (a car
    tilted 14 degrees) sees its low side's ground close by and heights shifted, so it is described levelled."""
    if plane is None:
        return None
    n = np.asarray(plane[:3], np.float64)
    n = n / np.linalg.norm(n)
    tilt = float(np.arccos(np.clip(n[2], -1.0, 1.0)))
    if n[2] <= 0 or tilt <= np.arctan2(band, radius):
        return None
    axis = np.cross(n, [0.0, 0.0, 1.0])  # rotate n onto +z about n x z (Rodrigues)
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(tilt) * K + (1 - np.cos(tilt)) * K @ K


class _HeightGrid:
    """A 2D grid (cell ``cell`` m) over points (N, 3): per cell the highest point above the local ground (the lowest
    point within GROUND_WINDOW cells), 0 where empty; ``ground`` the local ground (nan where nothing lies near).
    ``origin`` (2,) the corner of cell (0, 0); arrays indexed [ix, iy]."""

    def __init__(self, points: np.ndarray, cell: float, pad: float = 0.0) -> None:
        from scipy.ndimage import minimum_filter

        xy = points[:, :2].astype(np.float64)
        self.cell = float(cell)
        self.origin = xy.min(axis=0) - pad
        ij = np.floor((xy - self.origin) / cell).astype(np.int64)
        self.shape = tuple(int(v) for v in (np.ceil((xy.max(axis=0) + pad - self.origin) / cell).astype(int) + 1))
        flat = ij[:, 0] * self.shape[1] + ij[:, 1]
        n = self.shape[0] * self.shape[1]
        z = points[:, 2].astype(np.float32)
        zmax = np.full(n, -np.inf, np.float32)
        zmin = np.full(n, np.inf, np.float32)
        self.count = np.bincount(flat, minlength=n).reshape(self.shape)  # points per cell
        np.maximum.at(zmax, flat, z)
        np.minimum.at(zmin, flat, z)
        zmax, zmin = zmax.reshape(self.shape), zmin.reshape(self.shape)
        ground = minimum_filter(zmin, size=GROUND_WINDOW, mode="constant", cval=np.inf)
        occupied = np.isfinite(zmax)
        with np.errstate(invalid="ignore"):
            self.height = np.where(occupied, zmax - np.where(np.isfinite(ground), ground, zmax), 0.0).astype(np.float32)
        self.ground = np.where(np.isfinite(ground), ground, np.nan).astype(np.float32)
        self.zmax, self.occupied = zmax, occupied

    def index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ix, iy, inside) of map positions xy (..., 2)."""
        ij = np.floor((np.asarray(xy, np.float64) - self.origin) / self.cell).astype(np.int64)
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < self.shape[0]) & (ij[..., 1] >= 0) & (ij[..., 1] < self.shape[1])
        return np.clip(ij[..., 0], 0, self.shape[0] - 1), np.clip(ij[..., 1], 0, self.shape[1] - 1), inside

    def ground_at(self, xy: np.ndarray, fallback: float) -> np.ndarray:
        """The local ground height (m) at positions xy (K, 2); ``fallback`` where the grid has none."""
        ix, iy, inside = self.index(xy)
        g = np.where(inside, self.ground[ix, iy], np.nan)
        return np.where(np.isfinite(g), g, fallback)


class _PolarTemplate:
    """Which grid cells (offsets from the centre cell) fall in which (ring, sector) bin of a descriptor of ``rings``
    x ``sectors`` bins out to ``radius`` m (sectors counted counter-clockwise from +x, sector 0 starting at -pi)."""

    def __init__(self, radius: float, rings: int, sectors: int, cell: float) -> None:
        self.radius, self.rings, self.sectors, self.cell = radius, rings, sectors, cell
        # sample every bin densely enough that each gets its cells (small inner bins included), then deduplicate
        dr = min(cell / 2.0, radius / rings / 2.0)
        r = np.arange(dr / 2.0, radius, dr)
        pts = []
        for rr in r:
            n = max(sectors * 2, int(np.ceil(2 * np.pi * rr / (cell / 2.0))))
            a = -np.pi + (np.arange(n) + 0.5) * (2 * np.pi / n)
            pts.append(np.stack([rr * np.cos(a), rr * np.sin(a)], axis=1))
        p = np.concatenate(pts)
        ring = np.minimum((np.hypot(p[:, 0], p[:, 1]) / (radius / rings)).astype(np.int64), rings - 1)
        sector = np.minimum(((np.arctan2(p[:, 1], p[:, 0]) + np.pi) / (2 * np.pi / sectors)).astype(np.int64),
                            sectors - 1)
        off = np.floor(p / cell + 0.5).astype(np.int64)  # offsets of the cells holding the samples (centre cell 0)
        key = np.unique(np.stack([ring * sectors + sector, off[:, 0], off[:, 1]], axis=1), axis=0)
        self.bin, self.dx, self.dy = key[:, 0], key[:, 1], key[:, 2]
        self.starts = np.flatnonzero(np.r_[True, self.bin[1:] != self.bin[:-1]])

    def describe(self, grid: _HeightGrid, centres: np.ndarray) -> np.ndarray:
        """(K, rings, sectors) float32 descriptors of the grid around the map positions ``centres`` (K, 2)."""
        cx, cy, _ = grid.index(centres)
        out = np.empty((len(centres), self.rings * self.sectors), np.float32)
        padded = np.pad(grid.height, 1)  # index -1 / shape: the zero border (outside the grid)
        for a in range(0, len(centres), 64):  # batches of places: (64, cells of the template)
            ix = np.clip(cx[a:a + 64, None] + self.dx[None] + 1, 0, grid.shape[0] + 1)
            iy = np.clip(cy[a:a + 64, None] + self.dy[None] + 1, 0, grid.shape[1] + 1)
            out[a:a + 64] = np.maximum.reduceat(padded[ix, iy], self.starts, axis=1)
        return out.reshape(len(centres), self.rings, self.sectors)

    def observed(self, grid: _HeightGrid, centre: np.ndarray) -> np.ndarray:
        """(rings, sectors) bool: the bins about ``centre`` (2,) holding any point of the grid (a scan's seen bins)."""
        cx, cy, _ = grid.index(np.asarray(centre, np.float64)[None])
        padded = np.pad(grid.count > 0, 1)
        ix = np.clip(cx[0] + self.dx + 1, 0, grid.shape[0] + 1)
        iy = np.clip(cy[0] + self.dy + 1, 0, grid.shape[1] + 1)
        return np.maximum.reduceat(padded[ix, iy], self.starts).reshape(self.rings, self.sectors)


def _match_observed(places: np.ndarray, query: np.ndarray, seen: np.ndarray,
                    chunk: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_match` on the bins the query saw only (``seen`` (R, S) bool): a place's bins facing the scan's unseen
    ones (beyond a tilted sensor's low-side horizon) are left out. Every shift at once: a place column's norm over the
    bins query column s saw, and its dot product with that column, for every (place column, query column) pair as two
    matrix products, then read off per shift (``chunk`` places at a time, to stay in cache); for a shortlist."""
    P, R, S = places.shape
    q = np.where(seen, query, 0.0).astype(np.float32)
    qn = np.linalg.norm(q, axis=0)  # (S,)
    qok = qn > 1e-6
    w = np.concatenate([seen.astype(np.float32), q], axis=1)  # (R, 2S): the seen mask, the masked query
    s = np.arange(S)
    at = ((s[None, :] + s[:, None]) % S * S + s[None, :]).ravel()  # (shift k, query column s) -> (place column, s)
    dist = np.empty(P, np.float64)
    shift = np.empty(P, np.int64)
    for a in range(0, P, chunk):
        pt = np.asarray(places[a:a + chunk], np.float32).transpose(0, 2, 1)  # (n, S, R)
        n = len(pt)
        sq = (pt * pt) @ w[:, :S]  # (n, place column, query column): squared norms over the seen bins
        dot = pt @ w[:, S:]
        pn = np.take(sq.reshape(n, S * S), at, axis=1).reshape(n, S, S)  # (n, shift k, query column s)
        dot = np.take(dot.reshape(n, S * S), at, axis=1).reshape(n, S, S)
        np.sqrt(pn, out=pn)
        pok = pn > 1e-6
        either = (pok | qok).sum(axis=2)
        both = np.logical_and(pok, qok, out=pok)
        np.multiply(pn, qn, out=pn)
        sim = np.divide(dot, pn, out=np.zeros_like(dot), where=both).sum(axis=2) / np.maximum(either, 1)
        k = np.argmax(sim, axis=1)
        shift[a:a + n] = k
        dist[a:a + n] = 1.0 - sim[np.arange(n), k]
    return dist, shift


def _normalise_columns(desc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., R, S) -> (columns scaled to unit norm, (..., S) 1.0 where a column is not empty)."""
    norm = np.linalg.norm(desc, axis=-2, keepdims=True)
    nonzero = norm > 1e-6
    return np.where(nonzero, desc / np.where(nonzero, norm, 1.0), 0.0).astype(np.float32), nonzero[..., 0, :]


def _spectra(places: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The places' part of :func:`_match`, (P, R, S) -> (their normalised columns' spectra (P, R, S // 2 + 1),
    their non-empty columns' spectra (P, S // 2 + 1), their non-empty column counts (P, 1)): the same for every
    query, computed once per map."""
    pn, pmask = _normalise_columns(places)
    return (np.fft.rfft(pn, axis=-1), np.fft.rfft(pmask.astype(np.float32), axis=-1),
            pmask.sum(axis=-1, keepdims=True))


def _match(places: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray],
           query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scan Context distance of the query (R, S) to every place (P, R, S) (or their :func:`_spectra`) at every
    column shift: -> (distance (P,) in [0, 1] (mean cosine distance of the columns both have), shift (P,) int: place
    column (s + shift) % S matches query column s). Circular correlations by FFT over the sectors."""
    dist, shift = _match_many(places, query[None])
    return dist[0], shift[0]


def _match_many(places: np.ndarray | tuple[np.ndarray, np.ndarray, np.ndarray],
                query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_match` of K queries (K, R, S) at once: -> (distance (K, P), shift (K, P))."""
    fp, fpmask, psum = _spectra(places) if isinstance(places, np.ndarray) else places
    qn, qmask = _normalise_columns(query)  # (K, R, S), (K, S)
    S = query.shape[-1]
    fq = np.conj(np.fft.rfft(qn, axis=-1))  # (K, R, F)
    # one query at a time, not one matrix product: numpy's BLAS threads contend with the network's on 2 cores
    prod = np.stack([(fp * f[None]).sum(axis=1) for f in fq])  # (K, P, F)
    corr = np.fft.irfft(prod, n=S, axis=-1)  # (K, P, S): sum_s <p[:, s+k], q[:, s]>
    both = np.fft.irfft(fpmask[None] * np.conj(np.fft.rfft(qmask.astype(np.float32), axis=-1))[:, None], n=S,
                        axis=-1)  # (K, P, S) columns non-empty in both
    either = psum[None] + qmask.sum(axis=-1)[:, None, None] - both  # columns non-empty in one of them
    sim = corr / np.maximum(either, 1.0)  # an empty column facing a full one counts as a mismatch
    shift = np.argmax(sim, axis=-1)
    best = np.take_along_axis(sim, shift[..., None], axis=-1)[..., 0]
    return (1.0 - best).astype(np.float64), shift
