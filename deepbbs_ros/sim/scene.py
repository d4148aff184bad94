"""Procedural outdoor worlds built along a road (no ROS).

A :class:`World` is fully determined by ``(scene, seed, length)``:

* a smooth terrain height field ``z = g(x, y)`` (a few long-wavelength sinusoids, slopes of a few %),
* a :class:`Route`: the road centreline made of straights, 90-degree turns and gentle curves; its
  heading stays within +-90 degrees of the start heading, so the road never comes back on itself,
* a road surface with lane markings, curbs and sidewalks (or verges), extruded along the route,
* objects placed along both sides (buildings, walls, fences, poles, signs, traffic lights, trees,
  bushes, parked cars, guard rails, barriers), each kept clear of the road corridor and of each
  other, with per-object randomness so that nothing repeats exactly,
* moving cars on the other lanes (constant speed along the route).

Geometry is grouped in 50 m chunks of route length and 40 m terrain tiles, so a simulator only
builds the part near the sensor (:meth:`World.static_mesh`), which keeps long drives cheap.
World frame: x, y horizontal, z up, metres; the route starts near the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.geometry import MeshBuilder, blob, box, cylinder

SCENES = ("urban", "suburban", "highway", "open_road")

CHUNK = 50.0  # m of route length per geometry chunk
TILE = 40.0  # m, terrain tile edge
TILE_RES = 4.0  # m, terrain grid spacing
ROAD_DZ = 0.03  # m, road surface above the terrain
CURB_DZ = 0.18  # m, sidewalk above the terrain

ALB_ROAD, ALB_MARK, ALB_WALK, ALB_VERGE, ALB_CURB = 0.10, 0.75, 0.35, 0.25, 0.40


@dataclass(frozen=True)
class Style:
    """Road and traffic parameters of one scene type (metres, m/s, degrees)."""

    half_width: float  # carriageway half width
    sidewalk: float  # sidewalk width behind a curb; 0 = no curb (verge)
    ego_offset: float  # ego lane centre, lateral (left positive)
    markings: tuple[tuple[float, bool], ...]  # (lateral offset, dashed)
    straight: tuple[float, float]  # straight segment length range
    turn90_prob: float  # probability that a segment end is a 90-degree turn
    turn_radius: tuple[float, float]
    curve_prob: float  # probability of a gentle curve instead
    curve_radius: tuple[float, float]
    curve_angle: tuple[float, float]
    v_cruise: tuple[float, float]
    a_lat: float  # m/s^2 allowed in curves
    stop_prob: float  # probability of a stop at an intersection / segment end
    stop_dwell: tuple[float, float]  # s
    start_stopped_prob: float
    terrain_amp: float  # m
    movers: tuple[tuple[float, int], ...]  # (lateral offset, +1 same direction / -1 oncoming)
    mover_gap: float  # mean gap between moving cars in a lane (m)
    mover_speed: tuple[float, float]


STYLES: dict[str, Style] = {
    "urban": Style(
        7.5,
        4.0,
        -1.8,
        ((0.0, False), (3.6, True), (-3.6, True)),
        (70, 220),
        0.55,
        (14, 20),
        0.0,
        (0, 0),
        (0, 0),
        (8.0, 13.0),
        2.0,
        0.45,
        (2.0, 7.0),
        0.5,
        0.8,
        ((1.8, -1),),
        45.0,
        (6.0, 13.0),
    ),
    "suburban": Style(
        5.5,
        2.0,
        -1.75,
        ((0.0, False),),
        (60, 200),
        0.35,
        (12, 18),
        0.35,
        (60, 160),
        (15, 45),
        (8.0, 12.0),
        2.2,
        0.3,
        (1.0, 3.0),
        0.3,
        1.5,
        ((1.75, -1),),
        90.0,
        (7.0, 12.0),
    ),
    "highway": Style(
        12.5,
        0.0,
        -6.3,
        (
            (0.9, False),
            (-0.9, False),
            (4.5, True),
            (-4.5, True),
            (8.1, True),
            (-8.1, True),
            (11.7, False),
            (-11.7, False),
        ),
        (250, 700),
        0.0,
        (0, 0),
        0.8,
        (600, 1500),
        (5, 25),
        (17.0, 20.0),
        2.0,
        0.0,
        (0, 0),
        0.0,
        2.0,
        ((2.7, -1), (6.3, -1), (9.9, -1), (-2.7, 1), (-9.9, 1)),
        80.0,
        (16.0, 30.0),
    ),
    "open_road": Style(
        4.0,
        0.0,
        -1.8,
        ((0.0, True), (3.6, False), (-3.6, False)),
        (120, 400),
        0.0,
        (0, 0),
        0.8,
        (150, 500),
        (10, 50),
        (13.0, 20.0),
        2.0,
        0.03,
        (1.0, 3.0),
        0.1,
        3.0,
        ((1.8, -1),),
        180.0,
        (12.0, 22.0),
    ),
}


# ---------------------------------------------------------------------------------------------
class Terrain:
    """Smooth height field g(x, y) = sum_k A_k sin(w_k . (x, y) + phi_k), wavelengths 200-600 m."""

    def __init__(self, rng: np.random.Generator, amp: float) -> None:
        k = 3
        self.amp = amp * rng.uniform(0.5, 1.0, k) / k
        lam = rng.uniform(200.0, 600.0, k)
        ang = rng.uniform(0, 2 * np.pi, k)
        self.w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / lam)[:, None]
        self.phi = rng.uniform(0, 2 * np.pi, k)
        self._tiles: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        return (self.amp * np.sin(arg)).sum(-1)

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(dg/dx, dg/dy)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        c = self.amp * np.cos(arg)
        return (c * self.w[:, 0]).sum(-1), (c * self.w[:, 1]).sum(-1)

    def tile(self, ix: int, iy: int) -> tuple[np.ndarray, np.ndarray]:
        """Mesh of terrain tile (ix, iy) covering [ix*TILE, (ix+1)*TILE] x [iy*TILE, (iy+1)*TILE]."""
        key = (ix, iy)
        if key not in self._tiles:
            n = int(round(TILE / TILE_RES)) + 1
            gx, gy = np.meshgrid(
                ix * TILE + np.arange(n) * TILE_RES, iy * TILE + np.arange(n) * TILE_RES, indexing="ij"
            )
            v = np.stack([gx, gy, self.height(gx, gy)], -1).reshape(-1, 3)
            i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
            a = (i * n + j).ravel()
            f = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
            self._tiles[key] = (v, f.astype(np.int64))
        return self._tiles[key]


# ---------------------------------------------------------------------------------------------
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


def _plan_route(style: Style, rng: np.random.Generator, length: float):
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


# ---------------------------------------------------------------------------------------------
class World:
    """Static scene geometry plus moving cars along one route.

    scene: one of :data:`SCENES`; seed: int; length: route length to build (m).
    """

    def __init__(self, scene: str, seed: int, length: float) -> None:
        if scene not in STYLES:
            raise SimulationError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
        self.scene, self.seed = scene, int(seed)
        self.style = st = STYLES[scene]
        sid = SCENES.index(scene)
        rng = np.random.default_rng([self.seed, sid, 101])
        self.terrain = Terrain(rng, st.terrain_amp)
        kappa, self.intersections, self.stops = _plan_route(st, rng, float(length))
        self.route = Route(kappa, heading0=float(rng.uniform(-np.pi, np.pi)))
        self._occ: dict[tuple[int, int], list[tuple[float, float, float]]] = {}
        self._chunks: dict[int, MeshBuilder] = {}
        self._populate(np.random.default_rng([self.seed, sid, 202]))
        self._road(np.random.default_rng([self.seed, sid, 303]))
        self.chunks = []  # (vertices, faces, albedo, xy_min, xy_max)
        for k in sorted(self._chunks):
            v, f, a = self._chunks[k].build()
            self.chunks.append((v, f, a, v[:, :2].min(0), v[:, :2].max(0)))
        del self._chunks, self._occ
        self._movers(np.random.default_rng([self.seed, sid, 404]))

    # ---- placement helpers ------------------------------------------------------------------
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

    # ---- object makers ------------------------------------------------------------------------
    def _building(self, rng, s, side, setback, width, depth, height, alb) -> None:
        off = side * (setback + depth / 2)
        if not self._free_rect(s, off, width, depth, setback - 0.5):
            return
        _, h, _ = self.route.sample(s)
        xy = self.route.lateral(s, off)
        base = np.array([*xy, self._ground(xy) - 0.5])
        yaw = float(h) + rng.normal(0, 0.02)
        self._add(s, box(base, (width, depth, height + 0.5), yaw), alb)
        if rng.uniform() < 0.4:  # set-back upper storeys
            self._add(
                s,
                box(base + [0, 0, height + 0.5], (width * rng.uniform(0.5, 0.9), depth * 0.7, rng.uniform(3, 12)), yaw),
                alb * 0.9,
            )
        for _ in range(rng.integers(0, 4)):  # pillars, bay windows, porches on the road-side facade
            ds_ = rng.uniform(-width / 2 + 1, width / 2 - 1)
            p_off = side * (setback - rng.uniform(0.2, 0.9) / 2)
            pxy = self.route.lateral(s + ds_, p_off)
            pz = self._ground(pxy) - 0.3 + rng.uniform(0, 4)
            self._add(
                s,
                box([*pxy, pz], (rng.uniform(0.8, 3.0), rng.uniform(0.3, 1.0), rng.uniform(2, 6)), yaw),
                float(np.clip(alb + rng.normal(0, 0.1), 0.05, 0.9)),
            )

    def _tree(self, rng, s, xy, scale=1.0, road_clear=0.0) -> None:
        crown_r = rng.uniform(1.5, 3.5) * scale
        if not self._free(xy, crown_r * 0.6, road_clear):
            return
        z = self._ground(xy) - 0.2
        trunk_h = rng.uniform(1.8, 3.5) * scale
        self._add(s, cylinder([*xy, z], rng.uniform(0.1, 0.25) * scale, trunk_h + 0.5, sides=5), 0.3)
        radii = (crown_r * rng.uniform(0.8, 1.2), crown_r * rng.uniform(0.8, 1.2), crown_r * rng.uniform(0.7, 1.3))
        self._add(s, blob([*xy, z + trunk_h + radii[2] * 0.8], radii, rng, 0.3), float(rng.uniform(0.3, 0.5)))

    def _bush(self, rng, s, xy, road_clear=0.0) -> None:
        r = rng.uniform(0.4, 1.3)
        if not self._free(xy, r, road_clear):
            return
        z = self._ground(xy)
        self._add(
            s,
            blob([*xy, z + r * 0.5], (r * rng.uniform(0.8, 1.6), r, r * rng.uniform(0.6, 1.0)), rng, 0.35),
            float(rng.uniform(0.3, 0.5)),
        )

    def _pole(self, rng, s, off, height, arm=0.0, radius=0.12, alb=0.45, sign_plate=False) -> None:
        xy = self.route.lateral(s, off)
        if not self._free(xy, 0.4, abs(off) - 0.3):
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
        if not self._free(xy, dims[0] * 0.45, abs(off) - 1.2):
            return
        alb = float(rng.uniform(0.1, 0.7))
        body, cab = self._car(s, off, yaw_rel + rng.normal(0, 0.03), dims, alb)
        self._add(s, body, alb)
        self._add(s, cab, 0.15)

    def _run(self, s, off, length, height, thick, alb, gap=0.0, posts=0.0) -> None:
        """Wall / fence / guard rail / barrier following the route from s to s + length."""
        seg = 4.0
        for a in np.arange(s, s + length, seg):
            xy = self.route.lateral(a + seg / 2, off)
            _, h, k = self.route.sample(a + seg / 2)
            if abs(k) * abs(off) > 0.8 or self.route.clearance(xy[None]) < abs(off) - 0.3:
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

    # ---- scene content ----------------------------------------------------------------------
    def _populate(self, rng: np.random.Generator) -> None:
        st, L = self.style, self.route.length
        W, walk = st.half_width, st.sidewalk
        for side in (1.0, -1.0):
            if self.scene == "urban":
                s = rng.uniform(0, 10)
                while s < L:
                    w = rng.uniform(10, 35)
                    if not self._near_intersection(s + w / 2, w / 2 + 9):
                        hgt = float(np.clip(rng.lognormal(np.log(14), 0.5), 6, 60))
                        self._building(
                            rng,
                            s + w / 2,
                            side,
                            W + walk + rng.uniform(0, 3),
                            w,
                            rng.uniform(10, 25),
                            hgt,
                            float(rng.uniform(0.15, 0.6)),
                        )
                    s += w + (rng.uniform(8, 20) if rng.uniform() < 0.15 else rng.uniform(0.3, 4))
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
            elif self.scene == "suburban":
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
                        elif u < 0.55:  # hedge
                            for a in np.arange(s + 1, s + lot - 1, 2.5):
                                self._bush(rng, a, self.route.lateral(a, f_off), W + walk)
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
            elif self.scene == "highway":
                self._run(0.0, side * (W + 0.6), L, 0.75, 0.08, 0.55, gap=0.45, posts=0.75)  # guard rail
                s = rng.uniform(0, 100)
                while s < L:  # noise walls on some stretches
                    n = rng.uniform(80, 300)
                    if rng.uniform() < 0.35:
                        self._run(
                            s, side * (W + rng.uniform(3, 5)), n, rng.uniform(3, 5), 0.3, float(rng.uniform(0.2, 0.5))
                        )
                    else:
                        for _ in range(int(n / 15)):
                            a = rng.uniform(s, s + n)
                            off = side * (W + rng.uniform(6, 45))
                            if rng.uniform() < 0.6:
                                self._tree(rng, a, self.route.lateral(a, off), 1.2, W + 4)
                            else:
                                self._bush(rng, a, self.route.lateral(a, off), W + 4)
                    s += n
                s = rng.uniform(0, 200)
                while s < L:  # sign posts
                    self._pole(rng, s, side * (W + 2.0), rng.uniform(3, 5), radius=0.1, sign_plate=True, alb=0.5)
                    s += rng.uniform(150, 400)
            else:  # open_road: low structure
                s = rng.uniform(0, 30)
                while s < L:
                    u = rng.uniform()
                    if u < 0.25:  # a small group of trees
                        c = rng.uniform(W + 5, W + 60)
                        for _ in range(rng.integers(1, 5)):
                            a = s + rng.uniform(-8, 8)
                            self._tree(rng, a, self.route.lateral(a, side * (c + rng.uniform(-6, 6))), 1.1, W + 3)
                    elif u < 0.45:
                        a = s + rng.uniform(-5, 5)
                        self._bush(rng, a, self.route.lateral(a, side * rng.uniform(W + 2, W + 30)), W + 1.5)
                    elif u < 0.48:  # a farm shed far off
                        self._building(
                            rng,
                            s,
                            side,
                            rng.uniform(25, 70),
                            rng.uniform(8, 20),
                            rng.uniform(6, 14),
                            rng.uniform(3.5, 7),
                            float(rng.uniform(0.2, 0.6)),
                        )
                    s += rng.uniform(15, 45)
                s = rng.uniform(0, 50)
                while s < L:  # delineator posts
                    self._pole(rng, s, side * (W + 0.5), 1.0, radius=0.06, alb=0.8)
                    s += rng.uniform(45, 55)
                if side > 0:
                    s = rng.uniform(0, 50)
                    while s < L:  # power line poles
                        self._pole(rng, s, side * (W + rng.uniform(4, 7)), rng.uniform(8, 10), radius=0.15, alb=0.3)
                        s += rng.uniform(45, 65)
        if self.scene == "highway":
            self._run(0.0, 0.0, L, 0.85, 0.5, 0.5)  # median barrier
            s = rng.uniform(0, 60)
            while s < L:  # median lamp posts
                self._pole(rng, s, 0.0 + 1e-3, rng.uniform(10, 12), arm=1.8, radius=0.15)
                s += rng.uniform(45, 70)
        if self.scene == "urban":  # traffic lights at the corners of each intersection
            for si, _ in self.intersections:
                for side, ds_ in ((1.0, 9.0), (-1.0, -9.0)):
                    self._pole(rng, si + ds_, side * (W + 0.5), 5.5, arm=3.0, radius=0.12, alb=0.2, sign_plate=True)

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
            z = self.terrain.height(p[..., 0], p[..., 1]) + dzs[None, :]
            v = np.concatenate([p, z[..., None]], -1).reshape(-1, 3)
            nj, ni = len(s), len(offs)
            j, i = np.meshgrid(np.arange(nj - 1), np.arange(ni - 1), indexing="ij")
            a = (j * ni + i).ravel()
            f = np.concatenate([np.stack([a, a + ni, a + ni + 1], 1), np.stack([a, a + ni + 1, a + 1], 1)])
            alb = np.broadcast_to(strip_alb, (nj - 1, ni - 1)).copy()
            dash_on = (np.mod(s[:-1], 9.0) < 3.0)[:, None]
            alb = np.where(is_mark[None, :] & (~dashed[None, :] | dash_on), ALB_MARK, alb)
            alb = alb + rng.normal(0, 0.015, alb.shape)  # asphalt patches, worn paint
            self._add(k * CHUNK, (v, f.astype(np.int64)), np.tile(alb.ravel(), 2).astype(np.float32))

    def _movers(self, rng: np.random.Generator) -> None:
        """Moving cars: arrays s0 (M,), offset (M,), direction (M,), speed (M,), dims (M, 3), albedo (M,)."""
        st, L = self.style, self.route.length
        rows = []
        for off, direction in st.movers:
            s = rng.exponential(st.mover_gap)
            while s < L:
                big = self.scene == "highway" and rng.uniform() < 0.2
                dims = (
                    (rng.uniform(9, 16), 2.5, rng.uniform(3.0, 4.0))
                    if big
                    else (rng.uniform(3.9, 5.2), rng.uniform(1.7, 2.0), rng.uniform(1.4, 1.9))
                )
                rows.append((s, off, direction, rng.uniform(*st.mover_speed), *dims, rng.uniform(0.1, 0.7)))
                s += dims[0] + 4.0 + rng.exponential(st.mover_gap)
        self.movers = np.array(rows, dtype=np.float64).reshape(-1, 8)

    # ---- queries ------------------------------------------------------------------------------
    def static_mesh(self, center_xy: np.ndarray, radius: float):
        """Everything static within ``radius`` (m) of ``center_xy``: vertices (V, 3) float64 world,
        faces (F, 3) int64, albedo (F,) float32, plus the keys of the parts used."""
        c = np.asarray(center_xy, dtype=np.float64)
        vs, fs, as_, nv = [], [], [], 0
        for v, f, a, lo, hi in self.chunks:
            if np.linalg.norm(np.maximum(0, np.maximum(lo - c, c - hi))) <= radius:
                vs.append(v)
                fs.append(f + nv)
                as_.append(a)
                nv += len(v)
        i0, i1 = int((c[0] - radius) // TILE), int((c[0] + radius) // TILE)
        j0, j1 = int((c[1] - radius) // TILE), int((c[1] + radius) // TILE)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                lo = np.array([i * TILE, j * TILE])
                if np.linalg.norm(np.maximum(0, np.maximum(lo - c, c - lo - TILE))) <= radius:
                    v, f = self.terrain.tile(i, j)
                    vs.append(v)
                    fs.append(f + nv)
                    as_.append(np.full(len(f), ALB_VERGE, np.float32))
                    nv += len(v)
        return np.concatenate(vs), np.concatenate(fs), np.concatenate(as_)

    def moving_mesh(self, t: float, center_xy: np.ndarray, radius: float):
        """Moving cars at time ``t`` (s) within ``radius`` of ``center_xy``: vertices, faces, albedo."""
        b = MeshBuilder()
        if len(self.movers):
            m = self.movers
            s = m[:, 0] + m[:, 2] * m[:, 3] * t
            ok = (s > 0) & (s < self.route.length)
            if ok.any():
                xy = self.route.lateral(s[ok], m[ok, 1])
                near = np.linalg.norm(xy - np.asarray(center_xy)[:2], axis=1) < radius
                for row, si in zip(m[ok][near], s[ok][near]):
                    yaw_rel = 0.0 if row[2] > 0 else np.pi
                    body, cab = self._car(float(si), float(row[1]), yaw_rel, tuple(row[4:7]), float(row[7]))
                    b.add(body, float(row[7]))
                    b.add(cab, 0.15)
        return b.build()
