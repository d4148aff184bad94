"""The built structures along the road scenes: sign gantries, overpasses, sign boards, poles (lamps, signs) and
runs of wall, fence, guard rail or barrier, each placed clear of the road and of the others (no ROS)."""

from __future__ import annotations

import math

import numpy as np

from deepbbs_ros.sim.geometry import box, cylinder
from deepbbs_ros.sim.placement import Placement


class StreetFurniture(Placement):
    """Structure makers of a :class:`~deepbbs_ros.sim.scene.World` (the base of sim/objects.py's
    ``ObjectMakers``): each draws its own randomness from the ``rng`` given, reserves its room
    (:class:`~deepbbs_ros.sim.placement.Placement`) and adds its mesh to its chunk."""

    def _gantry(self, rng, s) -> None:
        """Sign gantry spanning the carriageways: two posts, a truss beam and sign panels."""
        W = self.style.half_width
        _, h, _ = self.route.sample(s)
        c = self.route.lateral(s, 0.0)
        z = self._ground(c)
        for e in (-1, 1):
            p = self.route.lateral(s, e * (W + 1.5))
            if not self._free(p, 0.6, W + 1.0):
                return
        for e in (-1, 1):
            p = self.route.lateral(s, e * (W + 1.5))
            self._add(s, cylinder([*p, self._ground(p) - 0.3], 0.3, 7.9, sides=6), 0.4)
        self._add(s, box([*c, z + 6.6], (1.0, 2 * W + 3.2, 1.2), float(h)), 0.45)
        for off in rng.choice([-9.0, -5.0, -1.5, 1.5, 5.0, 9.0], size=rng.integers(1, 4), replace=False):
            p = self.route.lateral(s - 0.6, off)
            self._add(s, box([*p, z + 5.4], (0.15, rng.uniform(3.0, 4.5), rng.uniform(2.0, 3.0)), float(h)), 0.85)

    def _overpass(self, rng, s) -> None:
        """A bridge crossing over the road at 60-120 degrees: deck, parapets, piers and abutments."""
        W = self.style.half_width
        _, h, _ = self.route.sample(s)
        c = self.route.lateral(s, 0.0)
        a = float(h) + math.radians(rng.uniform(60, 120))
        dv = np.array([math.cos(a), math.sin(a)])
        sin_a = abs(math.sin(a - float(h)))
        half = (W + 22.0) / sin_a
        ends = [c + e * half * dv for e in (-1, 1)]
        if self.route.clearance(np.array(ends)) < W + 15:
            return
        z = self._ground(c) + rng.uniform(5.8, 7.0)
        wd = rng.uniform(9.0, 14.0)
        alb = float(rng.uniform(0.3, 0.55))
        deck = box([*c, z], (2 * half, wd, 1.3), a)
        self._add(s, deck, alb)
        nrm = np.array([-dv[1], dv[0]])
        for e in (-1, 1):
            self._add(s, box([*(c + e * (wd / 2 - 0.2) * nrm), z + 1.3], (2 * half, 0.4, 1.0), a), alb)
        for t in (-(W + 4.0) / sin_a, 0.0, (W + 4.0) / sin_a):
            for q in (-wd / 3, 0.0, wd / 3):
                p = c + t * dv + q * nrm
                self._add(s, cylinder([*p, self._ground(p) - 0.3], 0.55, z - self._ground(p) + 0.3, sides=8), alb)
        for e in (-1, 1):  # abutments: walls down to the ground at both ends
            p = c + e * (half - 1.0) * dv
            g = self._ground(p)
            self._add(s, box([*p, min(g, z) - 1.0], (2.0, wd, z - min(g, z) + 1.0), a), alb)
        for t in np.arange(-half, half, 3.0):
            p = c + t * dv
            if self.route.clearance(p[None]) > W + 3:
                self._free(p, wd / 2, 0.0)

    def _sign_board(self, rng, s, off) -> None:
        """Large roadside sign: a panel on two posts."""
        xy = self.route.lateral(s, off)
        if not self._free(xy, 2.5, abs(off) - 0.5):
            return
        _, h, _ = self.route.sample(s)
        w, ph = rng.uniform(2.5, 5.0), rng.uniform(2.0, 3.5)
        z = self._ground(xy)
        for e in (-1, 1):
            p = self.route.lateral(s, off + e * w / 3)
            self._add(s, cylinder([*p, z - 0.3], 0.08, ph + 0.3 + 2.0, sides=6), 0.45)
        self._add(s, box([*xy, z + ph], (0.1, w, rng.uniform(1.5, 2.5)), float(h)), 0.85)

    def _pole(self, rng, s, off, height, arm=0.0, radius=0.12, alb=0.45, sign_plate=False) -> None:
        xy = self.route.lateral(s, off)
        if self._on_side_road(xy, 0.5) or not self._free(xy, 0.4, abs(off) - 0.3):
            return
        _, h, _ = self.route.sample(s)
        z = self._ground(xy) - 0.2
        self._add(s, cylinder([*xy, z], radius, height + 0.2, sides=6), alb)
        if arm > 0:  # lamp arm pointing over the road
            axy = self.route.lateral(s, off - np.sign(off) * arm / 2)
            self._add(s, box([*axy, z + height], (0.25, arm, 0.2), float(h)), alb)
        if sign_plate:
            w = rng.uniform(0.6, 1.2)
            self._add(s, box([*xy, z + height - w], (0.05, w, w), float(h)), 0.9)

    def _run(self, s, off, length, height, thick, alb, gap=0.0, posts=0.0) -> None:
        """Wall / fence / guard rail / barrier following the route from s to s + length."""
        seg = 4.0
        for a in np.arange(s, s + length, seg):
            xy = self.route.lateral(a + seg / 2, off)
            _, h, k = self.route.sample(a + seg / 2)
            if abs(k) * abs(off) > 0.8 or self.route.clearance(xy[None]) < abs(off) - 0.3:
                continue
            if self._on_side_road(xy, thick + 0.3):
                continue
            z = self._ground(xy)
            self._add(
                a,
                box([*xy, z - 0.2 + gap], (seg * (1 + abs(k * off)) + 0.02, thick, height + 0.2 - gap), float(h)),
                alb,
            )
            if posts > 0:
                pxy = self.route.lateral(a, off)
                self._add(a, box([*pxy, z - 0.2], (0.12, 0.12, posts + 0.2), float(h)), alb)
