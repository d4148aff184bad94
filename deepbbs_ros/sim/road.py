"""The road scenes' road surfaces: the carriageway with its markings, curbs and sidewalks (or verges) extruded along
the route, and the side roads' surfaces (no ROS)."""

from __future__ import annotations

import math

import numpy as np

from deepbbs_ros.sim.geometry import strip
from deepbbs_ros.sim.placement import CHUNK, Placement
from deepbbs_ros.sim.styles import ALB_CURB, ALB_MARK, ALB_ROAD, ALB_VERGE, ALB_WALK, CURB_DZ, ROAD_DZ


class RoadSurfaces(Placement):
    """The road surfaces of a :class:`~deepbbs_ros.sim.scene.World` (``_road``, ``_side_roads``)."""

    def _road(self, rng: np.random.Generator) -> None:
        """Road surface, markings, curbs and sidewalks (or verges) extruded along the route."""
        st = self.style
        W, walk = st.half_width, st.sidewalk
        rows: list[tuple[float, float]] = []  # (lateral offset, dz), left to right
        if walk > 0:
            rows += [(W + walk + 0.6, 0.0), (W + walk, CURB_DZ), (W, CURB_DZ), (W, ROAD_DZ)]
        else:
            rows += [(W + 2.0, 0.0), (W, ROAD_DZ)]
        marks = sorted(st.markings, key=lambda m: -m[0])
        for off, _ in marks:
            rows += [(off + 0.075, ROAD_DZ), (off - 0.075, ROAD_DZ)]
        rows += [(-o, dz) for o, dz in reversed(rows)]
        offs = np.array([r[0] for r in rows])
        dzs = np.array([r[1] for r in rows])
        strip_alb = []
        for i in range(len(rows) - 1):
            a, b = rows[i], rows[i + 1]
            if a[0] == b[0]:
                strip_alb.append(ALB_CURB)
            elif a[1] == CURB_DZ and b[1] == CURB_DZ:
                strip_alb.append(ALB_WALK)
            elif a[1] != b[1]:
                strip_alb.append(ALB_VERGE)
            else:
                strip_alb.append(ALB_ROAD)
        strip_alb = np.array(strip_alb, dtype=np.float32)
        is_mark = np.zeros(len(strip_alb), bool)
        dashed = np.zeros(len(strip_alb), bool)
        for off, dash in st.markings:
            i = int(np.argmin(np.abs(offs[:-1] - (off + 0.075)) + np.abs(offs[1:] - (off - 0.075))))
            is_mark[i], dashed[i] = True, dash
        step = 1.0
        for k in range(int(self.route.length // CHUNK) + 1):
            s = np.arange(k * CHUNK, min((k + 1) * CHUNK, self.route.length) + 1e-9, step)
            if len(s) < 2:
                continue
            xy, h, kap = self.route.sample(s)
            inner = (offs[None, :] * kap[:, None]) > 0
            lim = 0.85 / np.maximum(np.abs(kap), 1e-9)
            o = np.where(inner, np.sign(offs) * np.minimum(np.abs(offs), lim[:, None]), offs[None, :])
            nrm = np.stack([-np.sin(h), np.cos(h)], -1)
            p = xy[:, None, :] + o[..., None] * nrm[:, None, :]
            dz = np.broadcast_to(dzs, (len(s), len(offs))).copy()
            for j in self.junctions:  # curb cuts: the side road's mouth is at road level
                mouth = np.abs(s - j["s"]) < j["hw"] / max(math.sin(j["angle"]), 0.2) + 1.5
                dz[np.ix_(mouth, (offs * j["side"] > 0) & (dzs == CURB_DZ))] = ROAD_DZ
            z = self.terrain.height(p[..., 0], p[..., 1]) + dz
            v, f = strip(np.concatenate([p, z[..., None]], -1))
            nj, ni = len(s), len(offs)
            alb = np.broadcast_to(strip_alb, (nj - 1, ni - 1)).copy()
            dash_on = (np.mod(s[:-1], 9.0) < 3.0)[:, None]
            alb = np.where(is_mark[None, :] & (~dashed[None, :] | dash_on), ALB_MARK, alb)
            alb = alb + rng.normal(0, 0.015, alb.shape)  # asphalt patches, worn paint
            self._add(k * CHUNK, (v, f), np.tile(alb.ravel(), 2).astype(np.float32))

    def _side_roads(self, rng: np.random.Generator) -> None:
        """Side-road surfaces (slightly below the main road where they overlap it) with verges."""
        for j in self.junctions:
            xy, hw = j["xy"], j["hw"]
            d = xy[-1] - xy[0]
            nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            offs = np.array([hw + 1.5, hw, -hw, -hw - 1.5])
            dz = np.array([0.0, ROAD_DZ - 0.006, ROAD_DZ - 0.006, 0.0])
            p = xy[:, None, :] + offs[None, :, None] * nrm
            z = self.terrain.height(p[..., 0], p[..., 1]) + dz
            v, f = strip(np.concatenate([p, z[..., None]], -1))
            alb = np.tile(np.array([ALB_VERGE, ALB_ROAD, ALB_VERGE], np.float32), len(xy) - 1)
            alb = alb + rng.normal(0, 0.015, alb.shape).astype(np.float32)
            self._add(j["s"], (v, f), np.tile(alb, 2))

