"""The road's centreline: straights, 90-degree turns and curves planned from a scene's style (no ROS)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from deepbbs_ros.sim.styles import Style


class Route:
    """Road centreline sampled every ``DS`` metres of arc length.

    s: (K,) arc length; xy: (K, 2) world; heading: (K,) radians (continuous, unwrapped);
    kappa: (K,) signed curvature (1/m, positive = turning left).
    """

    DS = 0.5

    def __init__(self, kappa: np.ndarray, heading0: float) -> None:
        self.kappa = np.asarray(kappa, dtype=np.float64)
        k = len(self.kappa)
        self.s = np.arange(k) * self.DS
        self.heading = heading0 + np.concatenate([[0.0], np.cumsum(self.kappa[:-1] * self.DS)])
        mid = self.heading[:-1] + 0.5 * self.kappa[:-1] * self.DS
        steps = np.stack([np.cos(mid), np.sin(mid)], 1) * self.DS
        self.xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, 0)])
        self._tree = cKDTree(self.xy[::2])

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def sample(self, s: np.ndarray | float):
        """-> xy (..., 2), heading (...,), kappa (...,) at arc length ``s`` (linear interpolation)."""
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.s[-1])
        xy = np.stack([np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])], -1)
        return xy, np.interp(s, self.s, self.heading), np.interp(s, self.s, self.kappa)

    def lateral(self, s: np.ndarray | float, offset: np.ndarray | float) -> np.ndarray:
        """World xy of the point ``offset`` metres left of the centreline at arc length ``s``."""
        xy, h, _ = self.sample(s)
        off = np.asarray(offset, dtype=np.float64)[..., None]
        return xy + off * np.stack([-np.sin(h), np.cos(h)], -1)

    def clearance(self, xy: np.ndarray) -> float:
        """Smallest distance (m) from any of the points ``xy (N, 2)`` to the centreline."""
        d, _ = self._tree.query(np.atleast_2d(xy))
        return float(np.min(d))


def plan_route(style: Style, rng: np.random.Generator, length: float):
    """-> kappa array, intersections [(s, is_turn)], stops [(s, dwell)]."""
    ds = Route.DS
    kap: list[np.ndarray] = []
    total, rel = 0.0, 0.0
    inters: list[tuple[float, bool]] = []
    stops: list[tuple[float, float]] = []
    first = True
    clamp = math.pi / 2 + 1e-9
    while total < length:
        seg = rng.uniform(*style.straight) + (80.0 if first else 0.0)
        first = False
        kap.append(np.zeros(int(seg / ds)))
        total += len(kap[-1]) * ds
        u = rng.uniform()
        if u < style.turn90_prob:
            ang, radius, is_turn = math.pi / 2, rng.uniform(*style.turn_radius), True
        elif u < style.turn90_prob + style.curve_prob:
            ang, radius, is_turn = (
                math.radians(rng.uniform(*style.curve_angle)),
                rng.uniform(*style.curve_radius),
                False,
            )
        else:
            ang, radius, is_turn = 0.0, 1.0, False
        if style.turn90_prob > 0 and not is_turn and ang == 0.0:
            inters.append((total, False))  # straight through a crossing
            if rng.uniform() < style.stop_prob:
                stops.append((total - 12.0, float(rng.uniform(*style.stop_dwell))))
        if ang > 0:
            sign = 1.0 if rng.uniform() < 0.5 else -1.0
            if abs(rel + sign * ang) > clamp:
                sign = -sign
            if abs(rel + sign * ang) <= clamp:
                rel += sign * ang
                n = int(ang * radius / ds)
                if is_turn:
                    inters.append((total + n * ds / 2, True))
                    if rng.uniform() < style.stop_prob:
                        stops.append((total - 6.0, float(rng.uniform(*style.stop_dwell))))
                kap.append(np.full(n, sign * ang / (n * ds)))
                total += n * ds
    return np.concatenate(kap), inters, stops
