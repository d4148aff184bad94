"""The objects of the road scenes: buildings, trees, bushes, hedges and cars here; poles, signs, gantries,
overpasses, walls and fences in sim/furniture.py; each placed clear of the road and of the others (no ROS)."""

from __future__ import annotations

import math

import numpy as np

from deepbbs_ros.sim.furniture import StreetFurniture
from deepbbs_ros.sim.geometry import box, clusters, cylinder, rot_z
from deepbbs_ros.sim.styles import ROAD_DZ


class ObjectMakers(StreetFurniture):
    """Object makers of a :class:`~deepbbs_ros.sim.scene.World`: each draws its own randomness from the ``rng``
    given, reserves its room (:class:`~deepbbs_ros.sim.placement.Placement`) and adds its mesh to its chunk."""

    def _building(self, rng, s, side, setback, width, depth, height, alb) -> bool:
        """A building of one to three boxes: plain, L-shaped (a wing reaching back) or with a recessed
        centre between two front bays, mostly parallel to the road but sometimes turned by up to
        30 degrees, with set-back upper storeys, balconies and bay windows / pillars."""
        off = side * (setback + depth / 2)
        _, h, _ = self.route.sample(s)
        xy = self.route.lateral(s, off)
        turned = rng.uniform() < 0.25
        dyaw = rng.uniform(-0.5, 0.5) if turned else rng.normal(0, 0.02)
        if turned and self.route.clearance(self._corners(xy, float(h) + dyaw, [(0, 0, width, depth)])) < setback - 0.5:
            dyaw = rng.normal(0, 0.02)  # no room to turn it: parallel to the road
        yaw = float(h) + dyaw
        R = rot_z(yaw)[:2, :2]
        parts = [(0.0, 0.0, width, depth, height)]  # local x (along), y (towards +side), size
        u = rng.uniform()
        if u < 0.35:  # L: a wing reaching back from one end
            ww, dw = width * rng.uniform(0.3, 0.55), depth * rng.uniform(0.8, 1.6)
            parts.append((rng.choice([-1, 1]) * (width - ww) / 2, side * (depth / 2 + dw / 2 - 0.1), ww, dw,
                          height * rng.uniform(0.6, 1.1)))
        elif u < 0.6 and width > 12:  # recessed centre between two front bays
            rd, bw = rng.uniform(1.0, 3.0), rng.uniform(2.5, min(6.0, width / 4))
            parts[0] = (0.0, side * rd / 2, width, depth - rd, height)
            for e in (-1, 1):
                parts.append((e * (width - bw) / 2, -side * (depth - rd) / 2, bw, rd + 0.1,
                              height * rng.uniform(0.7, 1)))
        corners = self._corners(xy, yaw, parts)
        if self.route.clearance(corners) < setback - 0.5 or self._on_side_road(corners, 1.0):
            parts = parts[:1] if u < 0.35 else [(0.0, 0.0, width, depth, height)]  # plain box instead
            corners = self._corners(xy, yaw, parts)
            if self.route.clearance(corners) < setback - 0.5 or self._on_side_road(corners, 1.0):
                return False
        if not self._free(xy, 0.5 * math.hypot(width, depth), 0.0):
            return False
        z0 = self._ground(xy) - 0.5
        for lx, ly, sx, sy, hh in parts:
            self._add(s, box([*(R @ [lx, ly] + xy), z0], (sx, sy, hh + 0.5), yaw), alb)
        if rng.uniform() < 0.4:  # set-back upper storeys
            self._add(s, box([*xy, z0 + height + 0.5], (width * rng.uniform(0.5, 0.9), depth * 0.7, rng.uniform(3, 12)),
                             yaw), alb * 0.9)
        front = -side * (depth / 2)  # local y of the road-side facade of the main box
        if self.scene in ("urban", "suburban") and rng.uniform() < 0.5:  # balconies with railings
            bw = rng.uniform(2.0, 4.0)
            xs = np.arange(-width / 2 + bw, width / 2 - bw / 2, rng.uniform(bw + 1.0, bw + 4.0))
            for fz in np.arange(3.0, height - 1.0, 3.0):
                for lx in xs:
                    c = R @ [lx, front - side * 0.6] + xy
                    self._add(s, box([*c, z0 + 0.5 + fz], (bw, 1.2, 0.15), yaw), alb * 0.8)
                    c = R @ [lx, front - side * 1.15] + xy
                    self._add(s, box([*c, z0 + 0.65 + fz], (bw, 0.06, 1.0), yaw), 0.3)
        for _ in range(rng.integers(0, 4)):  # pillars, bay windows, porches on the road-side facade
            lx = rng.uniform(-width / 2 + 1, width / 2 - 1)
            dd = rng.uniform(0.2, 0.9)
            c = R @ [lx, front - side * dd / 2] + xy
            self._add(s, box([*c, z0 + 0.2 + rng.uniform(0, 4)], (rng.uniform(0.8, 3.0), dd, rng.uniform(2, 6)), yaw),
                      float(np.clip(alb + rng.normal(0, 0.1), 0.05, 0.9)))
        return True


    def _tree(self, rng, s, xy, scale=1.0, road_clear=0.0) -> None:
        """Trunk plus a porous crown of leaf clusters (broadleaf, or a slender conifer)."""
        crown_r = rng.uniform(1.5, 3.5) * scale
        if self._on_side_road(xy, crown_r * 0.5) or not self._free(xy, crown_r * 0.6, road_clear):
            return
        z = self._ground(xy) - 0.2
        trunk_h = rng.uniform(1.8, 3.5) * scale
        if rng.uniform() < 0.3:  # conifer
            radii = (crown_r * 0.6, crown_r * 0.6, crown_r * rng.uniform(1.4, 2.2))
            trunk_h *= 0.5
        else:
            radii = (crown_r * rng.uniform(0.8, 1.2), crown_r * rng.uniform(0.8, 1.2), crown_r * rng.uniform(0.7, 1.3))
        self._add(s, cylinder([*xy, z], rng.uniform(0.1, 0.25) * scale, trunk_h + 0.5 + radii[2], sides=5), 0.3)
        n = int(3.5 * (radii[0] * radii[1] * radii[2]) ** (2 / 3)) + 6
        self._add(s, clusters([*xy, z + trunk_h + radii[2] * 0.8], radii, rng, n, rng.uniform(0.3, 0.45)),
                  float(rng.uniform(0.3, 0.5)))

    def _bush(self, rng, s, xy, road_clear=0.0) -> None:
        r = rng.uniform(0.4, 1.3)
        if self._on_side_road(xy, r) or not self._free(xy, r, road_clear):
            return
        z = self._ground(xy)
        radii = (r * rng.uniform(0.8, 1.6), r, r * rng.uniform(0.6, 1.0))
        self._add(s, clusters([*xy, z + r * 0.5], radii, rng, int(10 * r * r) + 6, 0.25), float(rng.uniform(0.3, 0.5)))

    def _hedge(self, rng, s, off, length, height, depth) -> None:
        """Hedge following the route from s to s + length: dense leaf clusters in 3 m blocks."""
        alb = float(rng.uniform(0.3, 0.5))
        for a in np.arange(s, s + length, 3.0):
            xy = self.route.lateral(a + 1.5, off)
            if self.route.clearance(xy[None]) < abs(off) - 0.3 or self._on_side_road(xy, depth):
                continue
            if not self._free(xy, 1.0, 0.0):
                continue
            _, h, _ = self.route.sample(a + 1.5)
            hh = height * rng.uniform(0.85, 1.15)
            c = np.array([*xy, self._ground(xy) + hh / 2])
            v, f = clusters([0, 0, 0], (1.6, depth / 2, hh / 2), rng, 40, 0.3)
            v = v @ rot_z(float(h)).T + c
            self._add(a, (v, f), alb)

    def _car(self, s, off, yaw_rel, dims, alb, z=None):
        xy = self.route.lateral(s, off)
        _, h, _ = self.route.sample(s)
        z = self._ground(xy) + ROAD_DZ if z is None else z
        length, width, height = dims
        yaw = float(h) + yaw_rel
        body = box([*xy, z + 0.3], (length, width, height * 0.5), yaw)
        cab_xy = xy - 0.1 * length * np.array([np.cos(yaw), np.sin(yaw)])
        cab = box([*cab_xy, z + 0.3 + height * 0.5], (length * 0.55, width * 0.9, height * 0.5 - 0.3), yaw)
        return body, cab

    def _parked_car(self, rng, s, off, yaw_rel=0.0) -> None:
        dims = (rng.uniform(3.9, 5.2), rng.uniform(1.7, 2.0), rng.uniform(1.4, 1.9))
        xy = self.route.lateral(s, off)
        if self._on_side_road(xy, 2.0) or not self._free(xy, dims[0] * 0.45, abs(off) - 1.2):
            return
        alb = float(rng.uniform(0.1, 0.7))
        yaw_rel = yaw_rel + rng.normal(0, 0.03)
        if self._day_rng is not None:  # another day: the same draws above (the world stays), then the day's
            if self._day_rng.uniform() < 0.4:
                return  # gone today (its spot stays reserved, so nothing else moves)
            alb = float(self._day_rng.uniform(0.1, 0.7))
            yaw_rel = yaw_rel + self._day_rng.normal(0, 0.03)
            dims = (float(self._day_rng.uniform(3.9, 5.2)), float(self._day_rng.uniform(1.7, 2.0)),
                    float(self._day_rng.uniform(1.4, 1.9)))
            s = s + float(self._day_rng.uniform(-0.5, 0.5))
        body, cab = self._car(s, off, yaw_rel, dims, alb)
        self._add(s, body, alb)
        self._add(s, cab, 0.15)
