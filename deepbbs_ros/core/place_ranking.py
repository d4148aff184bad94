"""A scan against a localization map's places (no ROS): its Scan Context descriptor (about the sensor and about points
``localization.descriptor_shift`` m around it), the bins it saw, and the places ranked by descriptor distance at every
yaw (core/descriptors.py: a circular correlation by FFT).

A mixin of :class:`~deepbbs_ros.core.localization.MapLocalizer`, which builds the places' descriptors (``_places``,
``descriptors``, ``_spectra``, ``template``). Frames as in core/localization.py.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.core.descriptors import _HeightGrid, _match_many, _match_observed
from deepbbs_ros.core.localization_types import MIN_SCAN_POINTS, _as_cloud
from deepbbs_ros.errors import LocalizationError


class PlaceRanking:
    """Describes a scan and ranks :class:`~deepbbs_ros.core.localization.MapLocalizer`'s places (module docstring)."""

    # -- the scan --------------------------------------------------------------------------------------------------
    def describe(self, scan: np.ndarray, centres: np.ndarray | None = None) -> np.ndarray:
        """(R, S) float32 descriptor of a raw scan (N, 3), sensor frame (its yaw: the columns' order), about the
        sensor; with ``centres`` (K, 2) (m, sensor frame): (K, R, S), one about each (about the sensor: the same)."""
        lc = self.config.localization
        pts = _as_cloud(scan, "scan")
        pts = pts[np.isfinite(pts).all(axis=1)]
        r = np.hypot(pts[:, 0], pts[:, 1])
        own = pts[r <= lc.descriptor_radius + lc.descriptor_cell]
        if len(own) < MIN_SCAN_POINTS:
            raise LocalizationError(f"scan: {len(own)} points within {lc.descriptor_radius:.0f} m")
        at_sensor = self.template.describe(_HeightGrid(own, lc.descriptor_cell, pad=lc.descriptor_radius),
                                           np.zeros((1, 2)))
        if centres is None:
            return at_sensor[0]
        cs = np.asarray(centres, np.float64).reshape(-1, 2)
        reach = float(np.hypot(cs[:, 0], cs[:, 1]).max(initial=0.0))
        out = np.empty((len(cs), *at_sensor.shape[1:]), np.float32)
        sensor = np.all(cs == 0.0, axis=1)
        out[sensor] = at_sensor[0]
        if not sensor.all():  # the points as far around each centre (a grid of its own: the cells fall elsewhere)
            wide = pts[r <= lc.descriptor_radius + lc.descriptor_cell + reach]
            grid = _HeightGrid(wide, lc.descriptor_cell, pad=lc.descriptor_radius + reach)
            out[~sensor] = self.template.describe(grid, cs[~sensor])
        return out

    def seen(self, scan: np.ndarray) -> np.ndarray:
        """(R, S) bool, the bins of :meth:`describe`'s descriptor about the sensor that hold any point of the scan."""
        lc = self.config.localization
        pts = scan[np.isfinite(scan).all(axis=1)]
        own = pts[np.hypot(pts[:, 0], pts[:, 1]) <= lc.descriptor_radius + lc.descriptor_cell]
        return self.template.observed(_HeightGrid(own, lc.descriptor_cell, pad=lc.descriptor_radius), np.zeros(2))

    @property
    def description_centres(self) -> np.ndarray:
        """(K, 2) the points of the scan's frame (m) :meth:`_global` describes a scan about: the sensor first, then
        ``localization.descriptor_shift`` m ahead, behind and to either side (a 3 x 3 grid; the sensor alone at 0)."""
        s = self.config.localization.descriptor_shift
        if s <= 0:
            return np.zeros((1, 2))
        g = np.array([0.0, -s, s])
        return np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)

    def rank(self, desc: np.ndarray, among: np.ndarray | None = None,
             centres: np.ndarray | None = None,
             seen: np.ndarray | None = None) -> list[tuple[int, float, float, np.ndarray]]:
        """[(place, descriptor distance, yaw of the scan in the map (rad), the point of the scan's frame (2,) that
        stands on the place)] best first, at most ``top_k`` places at least ``candidate_separation`` m apart, among the
        places ``among`` (indices; None: all). ``desc``: (R, S) about the sensor, or (K, R, S) about ``centres``
        (K, 2) (:meth:`describe`): each place keeps its best match over them (the first of equals). ``seen`` (R, S)
        (:meth:`seen`, a levelled scan): the sensor's descriptor compared on the bins it saw only, on the shortlist."""
        lc = self.config.localization
        idx = np.arange(len(self._places)) if among is None else np.asarray(among, dtype=np.int64)
        if len(idx) == 0:
            return []
        descs = desc[None] if desc.ndim == 2 else desc
        cs = np.zeros((1, 2)) if centres is None else np.asarray(centres, np.float64).reshape(-1, 2)
        if len(cs) != len(descs):
            raise LocalizationError(f"rank: {len(descs)} descriptors for {len(cs)} centres")
        skip = min(lc.descriptor_skip_rings, lc.descriptor_rings - 1)
        if 0 < lc.rank_shortlist < len(idx) and len(descs) > 1:
            # a large map: the descriptor about the first centre (the sensor) alone against every place, then all of
            # them against the places it ranks best only
            first = self._spectra if among is None else tuple(a[idx] for a in self._spectra)
            d0, _ = _match_many(first, descs[:1, skip:])
            idx = np.sort(idx[np.argpartition(d0[0], lc.rank_shortlist)[:lc.rank_shortlist]])
            among = idx
        spectra = self._spectra if among is None else tuple(a[idx] for a in self._spectra)
        dists, shifts = _match_many(spectra, descs[:, skip:])  # (K, P)
        if seen is not None and len(idx) <= max(lc.rank_shortlist, 1):
            dists[0], shifts[0] = _match_observed(self.descriptors[idx, skip:], descs[0, skip:], seen[skip:])
        which = np.argmin(dists, axis=0)  # the first of equals: the sensor's own first
        cols = np.arange(dists.shape[1])
        dist, shift = dists[which, cols], shifts[which, cols]
        order = np.argsort(dist, kind="stable")
        chosen: list[tuple[int, float, float, np.ndarray]] = []
        xy = self._places[:, :2, 3]
        for o in order:
            p = int(idx[o])
            if any(np.linalg.norm(xy[p] - xy[q]) < lc.candidate_separation for q, *_ in chosen):
                continue
            yaw = (int(shift[o]) * 2.0 * np.pi / lc.descriptor_sectors)
            chosen.append((p, float(dist[o]), yaw, cs[which[o]].copy()))
            if len(chosen) >= lc.top_k:
                break
        return chosen

