"""What stands along the roads of the town scenes (no ROS): buildings, walled lots, street furniture and parked cars in
``urban``, lots, houses and gardens in ``suburban``, traffic lights at urban intersections. Part of
:class:`~deepbbs_ros.sim.roadside.Roadside`, which draws them in its fixed order.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.geometry import box
from deepbbs_ros.sim.objects import ObjectMakers


class TownSides(ObjectMakers):
    """The urban and suburban road sides and the urban traffic lights (:class:`~deepbbs_ros.sim.roadside.Roadside`
    builds on it)."""

    def _urban_side(self, rng: np.random.Generator, side: float) -> None:
        """Buildings (or walled lots), fenced gaps, street lights, trees, signs, bins, parked cars."""
        L, W, walk = self.route.length, self.style.half_width, self.style.sidewalk
        s = rng.uniform(0, 10)
        while s < L:
            w = rng.uniform(10, 35)
            if not self._near_intersection(s + w / 2, w / 2 + 9):
                hgt = float(np.clip(rng.lognormal(np.log(14), 0.5), 6, 60))
                built = self._building(
                    rng,
                    s + w / 2,
                    side,
                    W + walk + rng.uniform(0, 3),
                    w,
                    rng.uniform(10, 25),
                    hgt,
                    float(rng.uniform(0.15, 0.6)),
                )
                if not built:  # no room for a building: a lot behind a wall
                    self._run(s, side * (W + walk + 0.4), w, rng.uniform(1.5, 2.6), 0.25,
                              float(rng.uniform(0.2, 0.6)))
            gap = rng.uniform(8, 20) if rng.uniform() < 0.15 else rng.uniform(0.3, 4)
            if gap > 8 and not self._near_intersection(s + w + gap / 2, gap / 2 + 9):  # fenced gap
                self._run(s + w, side * (W + walk + 0.4), gap, rng.uniform(1.2, 2.2), 0.06,
                          float(rng.uniform(0.3, 0.6)), gap=0.1, posts=2.4)
            s += w + gap
        s = rng.uniform(0, 30)
        while s < L:  # street lights
            self._pole(rng, s, side * (W + 0.6), rng.uniform(7, 9), arm=rng.uniform(1.5, 2.5))
            s += rng.uniform(25, 40)
        s = rng.uniform(0, 20)
        while s < L:  # street trees, signs, bins
            u = rng.uniform()
            if u < 0.5:
                self._tree(
                    rng, s, self.route.lateral(s, side * (W + walk * rng.uniform(0.5, 0.8))), 0.8, W + 1.0
                )
            elif u < 0.7:
                self._pole(rng, s, side * (W + 0.4), rng.uniform(2.2, 3.0), radius=0.05, sign_plate=True)
            elif u < 0.85:
                xy = self.route.lateral(s, side * (W + walk * 0.7))
                if self._free(xy, 0.6, W + 1.0):
                    _, h, _ = self.route.sample(s)
                    self._add(
                        s,
                        box(
                            [*xy, self._ground(xy)],
                            (rng.uniform(0.5, 1.5), 0.6, rng.uniform(0.8, 1.4)),
                            float(h),
                        ),
                        float(rng.uniform(0.2, 0.6)),
                    )
            s += rng.uniform(6, 25)
        s = rng.uniform(0, 8)
        while s < L:  # parked cars in the outer lane
            if rng.uniform() < 0.65 and not self._near_intersection(s, 18):
                self._parked_car(rng, s, side * (W - 1.1))
            s += rng.uniform(5.5, 9)

    def _suburban_side(self, rng: np.random.Generator, side: float) -> None:
        """Houses on lots with fences or hedges, garden trees and bushes, parked cars, street trees, utility poles."""
        L, W, walk = self.route.length, self.style.half_width, self.style.sidewalk
        s = rng.uniform(0, 10)
        while s < L:
            lot = rng.uniform(16, 32)
            c = s + lot / 2
            set_b = W + walk + rng.uniform(6, 14)
            if not self._near_intersection(c, lot / 2 + 6):
                self._building(
                    rng,
                    c,
                    side,
                    set_b,
                    rng.uniform(8, min(16, lot - 3)),
                    rng.uniform(8, 13),
                    rng.uniform(4.5, 8.5),
                    float(rng.uniform(0.25, 0.7)),
                )
                u = rng.uniform()
                f_off = side * (W + walk + rng.uniform(0.5, 1.5))
                if u < 0.35:  # picket fence
                    self._run(
                        s + 1,
                        f_off,
                        lot - 2,
                        rng.uniform(0.9, 1.5),
                        0.06,
                        float(rng.uniform(0.3, 0.7)),
                        posts=1.5,
                    )
                elif u < 0.75:  # hedge
                    self._hedge(rng, s + 1, f_off, lot - 2, rng.uniform(1.0, 2.2), rng.uniform(0.8, 1.5))
                for _ in range(rng.integers(1, 4)):
                    a = rng.uniform(s, s + lot)
                    self._tree(
                        rng, a, self.route.lateral(a, side * (W + walk + rng.uniform(2, 30))), 1.0, W + walk
                    )
                for _ in range(rng.integers(0, 4)):
                    a = rng.uniform(s, s + lot)
                    self._bush(rng, a, self.route.lateral(a, side * (W + walk + rng.uniform(1, 20))), W + walk)
                if rng.uniform() < 0.4:  # car in the driveway
                    self._parked_car(rng, c + side * 0, side * (W + walk + rng.uniform(3, 5)), np.pi / 2)
                if rng.uniform() < 0.2:
                    self._parked_car(rng, c, side * (W - 1.1))
            s += lot
        s = rng.uniform(0, 15)
        while s < L:  # street trees on the verge
            xy = self.route.lateral(s, side * (W + walk * 0.5 + rng.uniform(0, 1.5)))
            self._tree(rng, s, xy, 0.9, W + 0.8)
            s += rng.uniform(9, 25)
        if side > 0:
            s = rng.uniform(0, 40)
            while s < L:  # utility poles with a cross arm
                self._pole(
                    rng,
                    s,
                    side * (W + walk + 0.6),
                    rng.uniform(8.5, 10.5),
                    arm=rng.uniform(1.0, 2.0),
                    radius=0.15,
                    alb=0.3,
                )
                s += rng.uniform(35, 55)
        s = rng.uniform(0, 60)
        while s < L:
            self._pole(rng, s, side * (W + 0.4), rng.uniform(2.2, 2.8), radius=0.05, sign_plate=True)
            s += rng.uniform(40, 120)

    def _traffic_lights(self, rng: np.random.Generator) -> None:
        """Traffic lights at the corners of each intersection."""
        W = self.style.half_width
        for si, _ in self.intersections:
            for side, ds_ in ((1.0, 9.0), (-1.0, -9.0)):
                self._pole(rng, si + ds_, side * (W + 0.5), 5.5, arm=3.0, radius=0.12, alb=0.2, sign_plate=True)
