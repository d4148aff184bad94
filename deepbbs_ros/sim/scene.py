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

The parts live in their own modules: the scene types (``sim/styles.py``), the terrain (``sim/terrain.py``), the
route (``sim/route.py``), where objects may go (``sim/placement.py``), the objects (``sim/objects.py``), what stands
along each scene type's roads (``sim/roadside.py``) and the road surfaces (``sim/road.py``); their public names stay
importable from here.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.geometry import MeshBuilder
from deepbbs_ros.sim.placement import CHUNK
from deepbbs_ros.sim.road import RoadSurfaces
from deepbbs_ros.sim.roadside import Roadside
from deepbbs_ros.sim.route import Route, plan_route
from deepbbs_ros.sim.styles import (
    ALB_CURB,
    ALB_MARK,
    ALB_ROAD,
    ALB_VERGE,
    ALB_WALK,
    CURB_DZ,
    ROAD_DZ,
    SCENES,
    STYLES,
    Style,
)
from deepbbs_ros.sim.terrain import TILE, TILE_RES, Terrain

__all__ = [  # the public names, wherever they live
    "ALB_CURB", "ALB_MARK", "ALB_ROAD", "ALB_VERGE", "ALB_WALK", "CHUNK", "CURB_DZ", "EGO_HALF_SIZE", "ROAD_DZ",
    "SCENES", "STYLES", "TILE", "TILE_RES", "Route", "Style", "Terrain", "World",
]

EGO_HALF_SIZE = (2.5, 1.0)  # m, half the ego vehicle's length and width about its sensor: moving cars keep out


class World(Roadside, RoadSurfaces):
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
        sid = SCENES.index(scene)
        # the day's own randomness: never drawn from the world's generators, so the rest stays identical
        self._day_rng = None if day is None else np.random.default_rng([self.seed, sid, 909, self.day])
        self.style = st = STYLES[scene]
        rng = np.random.default_rng([self.seed, sid, 101])
        self.terrain = Terrain(rng, st.terrain_amp)
        kappa, self.intersections, self.stops = plan_route(st, rng, float(length))
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
