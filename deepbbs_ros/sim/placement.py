"""Where a road scene's objects may go: geometry chunks, reserved disks, junctions and side roads (no ROS).

:class:`Placement` is a part of :class:`~deepbbs_ros.sim.scene.World`: it reads the world's ``route``, ``terrain``,
``style``, ``scene`` and ``intersections`` and, while the world is built, keeps ``_chunks`` (the meshes per chunk of
route length), ``_occ`` (reserved disks on a 10 m grid) and the side roads' ``_jtree`` / ``_jclear``.
"""

from __future__ import annotations

import math

import numpy as np

from deepbbs_ros.sim.geometry import MeshBuilder, rot_z

CHUNK = 50.0  # m of route length per geometry chunk


class Placement:
    """Placement helpers of a :class:`~deepbbs_ros.sim.scene.World` (see the module docstring)."""

    def _add(self, s: float, mesh, albedo) -> None:
        k = int(max(s, 0.0) // CHUNK)
        self._chunks.setdefault(k, MeshBuilder()).add(mesh, albedo)

    def _free(self, xy: np.ndarray, radius: float, road_clear: float) -> bool:
        """True (and the disk is reserved) if the disk is clear of objects and of the road corridor."""
        if self.route.clearance(xy[None]) < road_clear:
            return False
        c = (int(xy[0] // 10), int(xy[1] // 10))
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for ox, oy, r in self._occ.get((c[0] + dx, c[1] + dy), ()):
                    if (ox - xy[0]) ** 2 + (oy - xy[1]) ** 2 < (r + radius) ** 2:
                        return False
        self._occ.setdefault(c, []).append((float(xy[0]), float(xy[1]), radius))
        return True

    def _free_rect(self, s: float, off: float, length: float, depth: float, road_clear: float) -> bool:
        """Footprint [s-l/2, s+l/2] x [off-d/2, off+d/2] (route coordinates) clear of the road corridor."""
        ss = np.array([s - length / 2, s + length / 2, s - length / 2, s + length / 2, s])
        oo = np.array([off - depth / 2, off - depth / 2, off + depth / 2, off + depth / 2, off])
        if self.route.clearance(self.route.lateral(ss, oo)) < road_clear:
            return False
        return self._free(self.route.lateral(s, off), 0.5 * math.hypot(length, depth), 0.0)

    def _ground(self, xy: np.ndarray) -> float:
        return float(self.terrain.height(xy[0], xy[1]))

    def _near_intersection(self, s: float, margin: float) -> bool:
        return any(abs(s - si) < margin for si, _ in self.intersections)

    def _plan_junctions(self, rng: np.random.Generator) -> list[dict]:
        """Side roads leaving the route at arbitrary angles (cross streets at urban crossings,
        slip roads on highways): dicts with s, side, angle, hw (half width), xy (K, 2) centreline
        samples every 2 m from the route's centreline (or, on highways, from the outer lane), and
        free_from (index of the first sample outside the main road)."""
        st, L = self.style, self.route.length
        W = st.half_width
        cands: list[tuple[float, float, float]] = []
        if self.scene == "urban":
            for si, turn in self.intersections:
                if not turn:
                    a = math.radians(90 + rng.uniform(-20, 20))
                    cands += [(si, 1.0, a), (si, -1.0, a)]
        s = 90.0 + rng.uniform(*st.junction_gap) * 0.3
        while s < L - 60:
            cands.append((s, 1.0 if rng.uniform() < 0.5 else -1.0, math.radians(rng.uniform(*st.junction_angle))))
            s += rng.uniform(*st.junction_gap)
        out = []
        for s, side, ang in sorted(cands):
            if any(abs(s - si) < 35 for si, turn in self.intersections if turn):
                continue
            if any(abs(s - j["s"]) < 25 and j["side"] == side for j in out):
                continue
            hw = rng.uniform(2.5, 3.5) if self.scene == "highway" else rng.uniform(2.8, 5.0)
            length = rng.uniform(200, 260) if self.scene == "highway" else rng.uniform(50, 110)
            start = side * (W - hw) if self.scene == "highway" else 0.0
            p0 = self.route.lateral(s, start)
            _, h, _ = self.route.sample(s)
            d = float(h) + side * ang
            t = np.arange(0.0, length, 2.0)
            xy = p0 + t[:, None] * np.array([math.cos(d), math.sin(d)])
            clear = np.array([self.route.clearance(p[None]) for p in xy])
            outside = W + hw + 1.5
            free_from = int(np.argmax(clear > outside)) if (clear > outside).any() else len(t)
            bad = np.flatnonzero((np.arange(len(t)) > free_from) & (clear < outside))
            n = int(bad[0]) if len(bad) else len(t)
            if n - free_from < 8:
                continue
            out.append({"s": float(s), "side": side, "angle": float(ang), "hw": float(hw), "xy": xy[:n],
                        "free_from": free_from})
        return out

    def _on_side_road(self, xy: np.ndarray, margin: float = 0.0) -> bool:
        if self._jtree is None:
            return False
        d, i = self._jtree.query(np.atleast_2d(xy))
        return bool(np.any(d < self._jclear[i] + margin))

    @staticmethod
    def _corners(xy, yaw, parts) -> np.ndarray:
        """World xy corners of footprints ``parts`` [(local x, local y, size x, size y, ...)]."""
        R = rot_z(yaw)[:2, :2]
        c = np.array([[p[0] + a * p[2] / 2, p[1] + b * p[3] / 2] for p in parts for a in (-1, 1) for b in (-1, 1)])
        return c @ R.T + xy
