"""Procedural outdoor worlds built along a road (no ROS).

A :class:`World` is fully determined by ``(scene, seed, length)``:

* a terrain height field ``z = g(x, y)``: long-wavelength sinusoids (slopes of a few %) under the
  roads, and beyond them roadside relief that fades in from 1 m past the road edge: ditches,
  embankments and cuttings, and short (25-90 m) hills, strongest on open roads and highways,
* a :class:`Route`: the road centreline made of straights, 90-degree turns (urban, suburban) and
  curves of radius 100 m to 2 km; its heading stays within +-90 degrees of the start heading, so
  the road never comes back on itself,
* a road surface with lane markings, curbs and sidewalks (or verges), extruded along the route,
* junctions: side roads leaving at arbitrary angles (cross streets at urban crossings, with curb
  cuts; slip roads diverging from highways), with their own surfaces and kept free of objects,
* objects placed along both sides, each kept clear of the roads and of each other, with per-object
  randomness so that nothing repeats exactly: buildings of one to three boxes (L-shapes, recessed
  fronts, turned up to 30 degrees off the road, set-back storeys, balconies, bay windows), trees
  with trunks and porous crowns of leaf clusters (rays pass through the gaps), bushes, hedges,
  tree lines, woods, poles, lamp posts, signs, sign boards, traffic lights, parked cars, fences
  and noise walls with posts, guard rails in stretches with breaks, median barriers, and on
  highways sign gantries and overpasses (deck, parapets, piers, abutments),
* moving cars on the other lanes (constant speed along the route; a drive in one of their lanes, e.g. the
  other way, never has one overlapping its own vehicle).

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
from deepbbs_ros.sim.geometry import MeshBuilder, box, clusters, cylinder, rot_z, strip

SCENES = ("urban", "suburban", "highway", "open_road")

CHUNK = 50.0  # m of route length per geometry chunk
TILE = 40.0  # m, terrain tile edge
TILE_RES = 2.0  # m, terrain grid spacing
ROAD_DZ = 0.03  # m, road surface above the terrain
EGO_HALF_SIZE = (2.5, 1.0)  # m, half the ego vehicle's length and width about its sensor: moving cars keep out
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
    hills: float = 0.0  # m, amplitude of the short roadside hills
    bank: float = 0.0  # slope of roadside embankments / cuttings
    ditch: float = 0.0  # m, depth of the roadside ditches
    junction_gap: tuple[float, float] = (150.0, 400.0)  # m between side roads (junctions)
    junction_angle: tuple[float, float] = (40.0, 140.0)  # degrees from the road's heading


STYLES: dict[str, Style] = {
    "urban": Style(
        7.5,
        4.0,
        -1.8,
        ((0.0, False), (3.6, True), (-3.6, True)),
        (70, 220),
        0.5,
        (14, 20),
        0.25,
        (100, 300),
        (10, 35),
        (8.0, 13.0),
        2.0,
        0.45,
        (2.0, 7.0),
        0.5,
        0.8,
        ((1.8, -1),),
        45.0,
        (6.0, 13.0),
        hills=0.3,
        bank=0.05,
        junction_gap=(120.0, 300.0),
        junction_angle=(55.0, 125.0),
    ),
    "suburban": Style(
        5.5,
        2.0,
        -1.75,
        ((0.0, False),),
        (60, 200),
        0.3,
        (12, 18),
        0.45,
        (100, 500),
        (15, 50),
        (8.0, 12.0),
        2.2,
        0.3,
        (1.0, 3.0),
        0.3,
        1.5,
        ((1.75, -1),),
        90.0,
        (7.0, 12.0),
        hills=1.0,
        bank=0.1,
        ditch=0.3,
        junction_gap=(70.0, 200.0),
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
        (150, 500),
        0.0,
        (0, 0),
        0.85,
        (700, 2000),
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
        hills=2.5,
        bank=0.3,
        ditch=0.6,
        junction_gap=(400.0, 900.0),
        junction_angle=(6.0, 12.0),
    ),
    "open_road": Style(
        4.0,
        0.0,
        -1.8,
        ((0.0, True), (3.6, False), (-3.6, False)),
        (60, 250),
        0.0,
        (0, 0),
        0.85,
        (100, 1000),
        (10, 60),
        (13.0, 20.0),
        2.0,
        0.03,
        (1.0, 3.0),
        0.1,
        3.0,
        ((1.8, -1),),
        180.0,
        (12.0, 22.0),
        hills=4.0,
        bank=0.35,
        ditch=0.7,
        junction_gap=(150.0, 450.0),
        junction_angle=(30.0, 150.0),
    ),
}


# ---------------------------------------------------------------------------------------------
class Terrain:
    """Height field g(x, y): long-wavelength sinusoids (200-600 m, slopes of a few %) everywhere, plus,
    away from the roads only, roadside relief: shorter hills (25-90 m wavelengths), embankments and
    cuttings (ground falling or rising with the distance from the road) and ditches just beside it.

    The relief is faded in from ``1 m`` beyond each road's edge (:meth:`attach_roads`), so every
    road corridor keeps the smooth long-wavelength surface the vehicle drives on.
    """

    def __init__(self, rng: np.random.Generator, amp: float) -> None:
        k = 3
        self.amp = amp * rng.uniform(0.5, 1.0, k) / k
        lam = rng.uniform(200.0, 600.0, k)
        ang = rng.uniform(0, 2 * np.pi, k)
        self.w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / lam)[:, None]
        self.phi = rng.uniform(0, 2 * np.pi, k)
        self._tiles: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._roads: cKDTree | None = None

    def attach_roads(self, xy: np.ndarray, edge: np.ndarray, rng: np.random.Generator, hills: float,
                     bank: float, ditch: float) -> None:
        """Roadside relief beyond the road corridors: centreline samples ``xy`` (K, 2) with their
        edge distance ``edge`` (K,) (m from the centreline); ``hills``: amplitude (m) of the short
        hills, ``bank``: slope of embankments / cuttings, ``ditch``: ditch depth (m)."""
        self._roads, self._edge = cKDTree(xy), np.asarray(edge, dtype=np.float64)
        k = 4
        self.h_amp = hills * rng.uniform(0.4, 1.0, k) / 2
        lam = rng.uniform(25.0, 90.0, k)
        ang = rng.uniform(0, 2 * np.pi, k)
        self.h_w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / lam)[:, None]
        self.h_phi = rng.uniform(0, 2 * np.pi, k)
        ang = rng.uniform(0, 2 * np.pi, 2)  # embankment / cutting: slowly varying sign and slope
        self.b_w = np.stack([np.cos(ang), np.sin(ang)], 1) * (2 * np.pi / rng.uniform(150, 400, 2))[:, None]
        self.b_phi, self.bank, self.ditch = rng.uniform(0, 2 * np.pi, 2), bank, ditch

    def _base(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        return (self.amp * np.sin(arg)).sum(-1)

    def _relief(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        if self._roads is None:
            return np.zeros(np.shape(x))
        d, i = self._roads.query(np.stack([x, y], -1).reshape(-1, 2))
        e = (d - self._edge[i]).reshape(np.shape(x)) - 1.0  # m beyond the corridor
        ramp = np.clip(e / 8.0, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)
        arg = x[..., None] * self.h_w[:, 0] + y[..., None] * self.h_w[:, 1] + self.h_phi
        hills = (self.h_amp * np.sin(arg)).sum(-1)
        b = np.sin(x[..., None] * self.b_w[:, 0] + y[..., None] * self.b_w[:, 1] + self.b_phi)
        bank = self.bank * np.clip(b[..., 0] * 1.6, -1, 1) * np.clip(e - 2.0, 0.0, 14.0)
        ditch = -self.ditch * (0.6 + 0.4 * b[..., 1]) * np.clip(1.0 - ((e - 1.0) / 1.2) ** 2, 0.0, 1.0)
        return ramp * hills + bank + ditch

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        return self._base(x, y) + self._relief(x, y)

    def gradient(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(dg/dx, dg/dy); the roadside relief by central differences (it is zero on the roads)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        arg = x[..., None] * self.w[:, 0] + y[..., None] * self.w[:, 1] + self.phi
        c = self.amp * np.cos(arg)
        gx, gy = (c * self.w[:, 0]).sum(-1), (c * self.w[:, 1]).sum(-1)
        if self._roads is not None:
            h = 0.05
            gx = gx + (self._relief(x + h, y) - self._relief(x - h, y)) / (2 * h)
            gy = gy + (self._relief(x, y + h) - self._relief(x, y - h)) / (2 * h)
        return gx, gy

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
    day: None (default) or an int: "another day" in the same world -- the same roads, buildings,
    vegetation and street furniture, but other parked cars (some of them gone, the rest repainted and
    parked a little differently) and other moving traffic. ``day=None`` is the world as always built.
    """

    def __init__(self, scene: str, seed: int, length: float, day: int | None = None) -> None:
        if scene not in STYLES:
            raise SimulationError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
        self.scene, self.seed = scene, int(seed)
        self.day = None if day is None else int(day)
        sid_ = SCENES.index(scene)
        # the day's own randomness: never drawn from the world's generators, so the rest stays identical
        self._day_rng = None if day is None else np.random.default_rng([self.seed, sid_, 909, self.day])
        self.style = st = STYLES[scene]
        sid = SCENES.index(scene)
        rng = np.random.default_rng([self.seed, sid, 101])
        self.terrain = Terrain(rng, st.terrain_amp)
        kappa, self.intersections, self.stops = _plan_route(st, rng, float(length))
        self.route = Route(kappa, heading0=float(rng.uniform(-np.pi, np.pi)))
        self._occ: dict[tuple[int, int], list[tuple[float, float, float]]] = {}
        self._chunks: dict[int, MeshBuilder] = {}
        self.junctions = self._plan_junctions(np.random.default_rng([self.seed, sid, 212]))
        edge = st.half_width + (st.sidewalk + 0.6 if st.sidewalk > 0 else 2.0)
        rxy, redge = [self.route.xy[::2]], [np.full(len(self.route.xy[::2]), edge)]
        for j in self.junctions:
            rxy.append(j["xy"])
            redge.append(np.full(len(j["xy"]), j["hw"] + 1.0))
        self.terrain.attach_roads(np.concatenate(rxy), np.concatenate(redge),
                                  np.random.default_rng([self.seed, sid, 111]), st.hills, st.bank, st.ditch)
        if self.junctions:
            jxy = np.concatenate([j["xy"] for j in self.junctions])
            self._jtree = cKDTree(jxy)
            self._jclear = np.concatenate([np.full(len(j["xy"]), j["hw"] + 1.0) for j in self.junctions])
            for j in self.junctions:  # keep objects off the side roads
                for p in j["xy"][j["free_from"]::2]:
                    c = (int(p[0] // 10), int(p[1] // 10))
                    self._occ.setdefault(c, []).append((float(p[0]), float(p[1]), j["hw"] + 1.0))
        else:
            self._jtree = None
        self._populate(np.random.default_rng([self.seed, sid, 202]))
        self._road(np.random.default_rng([self.seed, sid, 303]))
        self._side_roads(np.random.default_rng([self.seed, sid, 313]))
        self.chunks = []  # (vertices, faces, albedo, xy_min, xy_max)
        for k in sorted(self._chunks):
            v, f, a = self._chunks[k].build()
            self.chunks.append((v, f, a, v[:, :2].min(0), v[:, :2].max(0)))
        del self._chunks, self._occ, self._jtree
        mover_seed = [self.seed, sid, 404] if self.day is None else [self.seed, sid, 404, self.day]
        self._movers(np.random.default_rng(mover_seed))

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

    # ---- object makers ------------------------------------------------------------------------
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

    @staticmethod
    def _corners(xy, yaw, parts) -> np.ndarray:
        """World xy corners of footprints ``parts`` [(local x, local y, size x, size y, ...)]."""
        R = rot_z(yaw)[:2, :2]
        c = np.array([[p[0] + a * p[2] / 2, p[1] + b * p[3] / 2] for p in parts for a in (-1, 1) for b in (-1, 1)])
        return c @ R.T + xy

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
            elif self.scene == "highway":
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
            else:  # open_road: hedgerows, tree lines, woods, fields with fences, hills
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
        if self.scene == "highway":
            s = rng.uniform(60, 250)
            while s < L:  # overpasses and gantries
                if rng.uniform() < 0.5:
                    self._overpass(rng, s)
                else:
                    self._gantry(rng, s)
                s += rng.uniform(150, 450)
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
            dz = np.broadcast_to(dzs, (len(s), len(offs))).copy()
            for j in self.junctions:  # curb cuts: the side road's mouth is at road level
                mouth = np.abs(s - j["s"]) < j["hw"] / max(math.sin(j["angle"]), 0.2) + 1.5
                dz[np.ix_(mouth, (offs * j["side"] > 0) & (dzs == CURB_DZ))] = ROAD_DZ
            z = self.terrain.height(p[..., 0], p[..., 1]) + dz
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

    def moving_mesh(self, t: float, center_xy: np.ndarray, radius: float, ego_xy: np.ndarray | None = None):
        """Moving cars at time ``t`` (s) within ``radius`` of ``center_xy``: vertices, faces, albedo. With ``ego_xy``
        (2,), the ego vehicle's position: none whose body would overlap the ego's (EGO_HALF_SIZE about it; a drive in
        a lane the moving cars use, e.g. the other way, would otherwise put its sensor inside one)."""
        b = MeshBuilder()
        if len(self.movers):
            m = self.movers
            s = m[:, 0] + m[:, 2] * m[:, 3] * t
            ok = (s > 0) & (s < self.route.length)
            if ok.any():
                xy = self.route.lateral(s[ok], m[ok, 1])
                near = np.linalg.norm(xy - np.asarray(center_xy)[:2], axis=1) < radius
                if ego_xy is not None and near.any():
                    _, h, _ = self.route.sample(s[ok])
                    d = np.asarray(ego_xy, np.float64)[:2] - xy
                    along = np.abs(d[:, 0] * np.cos(h) + d[:, 1] * np.sin(h))
                    across = np.abs(-d[:, 0] * np.sin(h) + d[:, 1] * np.cos(h))
                    near &= ~((along < m[ok, 4] / 2 + EGO_HALF_SIZE[0]) & (across < m[ok, 5] / 2 + EGO_HALF_SIZE[1]))
                for row, si in zip(m[ok][near], s[ok][near]):
                    yaw_rel = 0.0 if row[2] > 0 else np.pi
                    body, cab = self._car(float(si), float(row[1]), yaw_rel, tuple(row[4:7]), float(row[7]))
                    b.add(body, float(row[7]))
                    b.add(cab, 0.15)
        return b.build()
