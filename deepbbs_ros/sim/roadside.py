"""What stands along a road scene's roads, per scene type: buildings and street furniture in town, lots and gardens
in the suburbs, guard rails, noise walls, gantries and overpasses on highways, hedgerows, woods and farms on open
roads (no ROS). The random draws come in a fixed order: the same seed builds the same world. The town's sides
(urban, suburban) are sim/town_side.py's.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.town_side import TownSides


class Roadside(TownSides):
    """The roadside content of a :class:`~deepbbs_ros.sim.scene.World` (``_populate``)."""

    def _populate(self, rng: np.random.Generator) -> None:
        """Both sides of the road (left, then right), then the scene's structures across it."""
        sides = {"urban": self._urban_side, "suburban": self._suburban_side, "highway": self._highway_side}
        for side in (1.0, -1.0):
            sides.get(self.scene, self._open_road_side)(rng, side)
        if self.scene == "highway":
            self._highway_across(rng)
        if self.scene == "urban":
            self._traffic_lights(rng)

    def _highway_side(self, rng: np.random.Generator, side: float) -> None:
        """Guard rails, noise walls, tree bands, hedges, warehouses, sign boards, distance posts."""
        L, W = self.route.length, self.style.half_width
        s = rng.uniform(0, 30)
        while s < L:  # guard rail in stretches, with breaks
            n = rng.uniform(40, 300)
            if rng.uniform() < 0.7:
                self._run(s, side * (W + 0.6), n, 0.75, 0.08, 0.55, gap=0.45, posts=0.75)
            s += n + rng.uniform(5, 60)
        s = rng.uniform(0, 100)
        while s < L:  # roadside stretches: noise walls, tree bands, hedges, open fields
            n = rng.uniform(60, 250)
            u = rng.uniform()
            if u < 0.25:  # noise wall with posts
                self._run(s, side * (W + rng.uniform(3, 5)), n, rng.uniform(3, 5), 0.3,
                          float(rng.uniform(0.2, 0.5)), posts=rng.uniform(4.5, 5.5))
            elif u < 0.45:
                self._hedge(rng, s, side * (W + rng.uniform(4, 7)), n, rng.uniform(1.5, 3.0), 1.8)
            if u >= 0.25 or rng.uniform() < 0.5:
                for _ in range(int(n / rng.uniform(4, 10))):
                    a = rng.uniform(s, s + n)
                    off = side * (W + rng.uniform(5, 80))
                    if rng.uniform() < 0.7:
                        self._tree(rng, a, self.route.lateral(a, off), 1.3, W + 4)
                    else:
                        self._bush(rng, a, self.route.lateral(a, off), W + 4)
            if rng.uniform() < 0.3:  # a warehouse / farm building 25-80 m off
                self._building(rng, s + n / 2, side, rng.uniform(25, 60), rng.uniform(15, 40),
                               rng.uniform(10, 25), rng.uniform(5, 12), float(rng.uniform(0.2, 0.6)))
            s += n
        s = rng.uniform(0, 150)
        while s < L:  # sign boards and sign posts
            if rng.uniform() < 0.5:
                self._sign_board(rng, s, side * (W + 3.0))
            else:
                self._pole(rng, s, side * (W + 2.0), rng.uniform(3, 5), radius=0.1, sign_plate=True, alb=0.5)
            s += rng.uniform(80, 250)
        s = rng.uniform(0, 50)
        while s < L:  # distance posts
            self._pole(rng, s, side * (W + 1.2), 1.1, radius=0.06, alb=0.8)
            s += rng.uniform(45, 55)

    def _open_road_side(self, rng: np.random.Generator, side: float) -> None:
        """Tree lines, hedgerows, woods, fenced fields, farms, delineators, signs, power lines."""
        L, W = self.route.length, self.style.half_width
        s = rng.uniform(0, 20)
        while s < L:
            n = rng.uniform(20, 120)
            u = rng.uniform()
            if u < 0.25:  # tree line along the road
                off = W + rng.uniform(3, 8)
                a = s + rng.uniform(0, 6)
                while a < s + n:
                    self._tree(rng, a, self.route.lateral(a, side * (off + rng.uniform(-1, 1))), 1.2, W + 2)
                    a += rng.uniform(5, 12)
            elif u < 0.45:  # hedgerow, a few trees in it
                off = W + rng.uniform(2.5, 5)
                self._hedge(rng, s, side * off, n, rng.uniform(1.2, 2.8), rng.uniform(1.2, 2.5))
                for _ in range(int(n / 25)):
                    a = rng.uniform(s, s + n)
                    self._tree(rng, a, self.route.lateral(a, side * (off + 1.5)), 1.1, W + 2)
            elif u < 0.65:  # wood
                for _ in range(int(n / 3)):
                    a = rng.uniform(s, s + n)
                    self._tree(rng, a, self.route.lateral(a, side * rng.uniform(W + 4, W + 50)), 1.3, W + 3)
            elif u < 0.85:  # field with a post-and-rail fence
                self._run(s, side * (W + rng.uniform(3, 6)), n, rng.uniform(1.0, 1.4), 0.05,
                          float(rng.uniform(0.3, 0.6)), gap=rng.uniform(0.6, 0.9), posts=1.3)
                for _ in range(rng.integers(0, 4)):
                    a = rng.uniform(s, s + n)
                    self._bush(rng, a, self.route.lateral(a, side * rng.uniform(W + 2, W + 30)), W + 1.5)
            else:  # a farm: buildings and trees
                for _ in range(rng.integers(1, 4)):
                    self._building(rng, s + rng.uniform(0, n), side, rng.uniform(12, 50), rng.uniform(8, 20),
                                   rng.uniform(6, 14), rng.uniform(3.5, 8), float(rng.uniform(0.2, 0.6)))
                for _ in range(rng.integers(2, 8)):
                    a = rng.uniform(s, s + n)
                    self._tree(rng, a, self.route.lateral(a, side * rng.uniform(W + 6, W + 40)), 1.1, W + 3)
            s += n
        s = rng.uniform(0, 50)
        while s < L:  # delineator posts
            self._pole(rng, s, side * (W + 0.5), 1.0, radius=0.06, alb=0.8)
            s += rng.uniform(45, 55)
        s = rng.uniform(0, 150)
        while s < L:  # road signs
            self._pole(rng, s, side * (W + 1.0), rng.uniform(2.2, 2.8), radius=0.05, sign_plate=True)
            s += rng.uniform(60, 200)
        if side > 0:
            s = rng.uniform(0, 50)
            while s < L:  # power line poles
                self._pole(rng, s, side * (W + rng.uniform(4, 7)), rng.uniform(8, 10), radius=0.15, alb=0.3)
                s += rng.uniform(45, 65)

    def _highway_across(self, rng: np.random.Generator) -> None:
        """Overpasses and sign gantries, the median barrier and its lamp posts."""
        L = self.route.length
        s = rng.uniform(60, 250)
        while s < L:  # overpasses and gantries
            if rng.uniform() < 0.5:
                self._overpass(rng, s)
            else:
                self._gantry(rng, s)
            s += rng.uniform(150, 450)
        self._run(0.0, 0.0, L, 0.85, 0.5, 0.5)  # median barrier
        s = rng.uniform(0, 60)
        while s < L:  # median lamp posts
            self._pole(rng, s, 0.0 + 1e-3, rng.uniform(10, 12), arm=1.8, radius=0.15)
            s += rng.uniform(45, 70)
