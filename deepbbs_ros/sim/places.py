"""Places off the road: indoor corridors and halls, a campus courtyard and a parking garage (no ROS).

A :class:`Place` is fully determined by ``(name, seed)``: a static triangle mesh (flat floor at z = 0),
a closed loop of waypoints the mounts (:mod:`deepbbs_ros.sim.mounts`) follow, and the ceiling height
(None under the open sky). The road scenes (:data:`~deepbbs_ros.sim.scene.SCENES`) stay in
:mod:`deepbbs_ros.sim.scene`; their random streams are not touched here.

* ``corridor``: an office floor, a rectangular corridor loop 2-3 m wide and 2.6-3.2 m high round a
  block of rooms, with door recesses, cabinets and ceiling lights;
* ``hall``: a 15-25 x 20-40 m hall, 6-10 m high, with columns, tables, shelves and a mezzanine;
* ``courtyard``: a campus square 40-70 m across, buildings of 8-20 m round it with passages between
  them, trees, benches, lamp posts and planters, open sky;
* ``garage``: a parking level with a 2.3-2.7 m ceiling, a grid of pillars, rows of parked cars along
  the aisles and ramps up to the next level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.errors import SimulationError
from deepbbs_ros.sim.geometry import MeshBuilder, box, clusters, cylinder, strip
from deepbbs_ros.sim.indoor import corridor, hall

PLACES = ("corridor", "hall", "courtyard", "garage")


@dataclass
class Place:
    """A static place: mesh (vertices (V, 3) float64, faces (F, 3), albedo (F,) float32), a closed loop
    ``path`` (K, 2) of waypoints on the floor (z = 0), ``ceiling`` height in metres or None."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray
    path: np.ndarray
    ceiling: float | None

    def floor_height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Floor height (m) under the path: the floor is flat at z = 0 (ramps lie off the path)."""
        return np.zeros(np.broadcast(np.asarray(x), np.asarray(y)).shape)


def _tree(b: MeshBuilder, rng: np.random.Generator, xy) -> None:
    crown = rng.uniform(1.5, 3.0)
    trunk = rng.uniform(2.0, 3.0)
    b.add(cylinder([*xy, 0.0], rng.uniform(0.12, 0.25), trunk + crown, sides=5), 0.3)
    radii = (crown, crown, crown * rng.uniform(0.7, 1.2))
    n = int(3.5 * (radii[0] * radii[1] * radii[2]) ** (2 / 3)) + 6
    b.add(clusters([*xy, trunk + 0.8 * radii[2]], radii, rng, n, rng.uniform(0.3, 0.45)), float(rng.uniform(0.3, 0.5)))


def courtyard(rng: np.random.Generator):
    """A square (40-70 m) closed by buildings with passages, trees, benches, lamp posts and planters."""
    half = rng.uniform(20.0, 35.0)
    b = MeshBuilder()
    b.add(box([0, 0, -0.3], (2 * half + 140, 2 * half + 140, 0.3)), 0.3)
    for side in range(4):  # each side: 2-4 buildings with 3-8 m passages between them
        rot = side * np.pi / 2
        c, s = np.cos(rot), np.sin(rot)
        x = -half - 5.0
        while x < half + 5.0:
            w = rng.uniform(10.0, 30.0)
            depth, height = rng.uniform(10.0, 18.0), rng.uniform(8.0, 20.0)
            cx, cy = x + w / 2, half + depth / 2 + rng.uniform(0.0, 3.0)
            b.add(box([c * cx - s * cy, s * cx + c * cy, 0.0], (w, depth, height), rot), float(rng.uniform(0.3, 0.7)))
            x += w + rng.uniform(3.0, 8.0)
    pad = half - 6.0  # the loop walked round the square; objects keep 1.5 m off it
    for _ in range(int(rng.integers(8, 16))):
        xy = rng.uniform(-half + 2, half - 2, 2)
        if np.min(np.abs(np.abs(xy) - pad)) < 3.0 and np.max(np.abs(xy)) < pad + 3.0:
            continue
        kind = rng.uniform()
        if kind < 0.45:
            _tree(b, rng, xy)
        elif kind < 0.7:  # bench
            b.add(box([*xy, 0.0], (1.8, 0.5, 0.45), rng.uniform(0, np.pi)), 0.4)
        elif kind < 0.85:  # lamp post
            b.add(cylinder([*xy, 0.0], 0.08, rng.uniform(3.5, 5.0), sides=6), 0.5)
        else:  # planter
            b.add(box([*xy, 0.0], (rng.uniform(1.5, 4.0), rng.uniform(1.0, 2.0), 0.6)), 0.35)
    path = np.array([[-pad, -pad], [pad, -pad], [pad, pad], [-pad, pad]])
    return b, path, None


def _car(b: MeshBuilder, rng: np.random.Generator, xy, yaw: float) -> None:
    length, width = rng.uniform(4.0, 4.9), rng.uniform(1.7, 1.9)
    alb = float(rng.uniform(0.1, 0.7))
    b.add(box([*xy, 0.2], (length, width, 0.8), yaw), alb)
    b.add(box([*xy, 1.0], (length * 0.55, width * 0.9, 0.45), yaw), 0.15)


def garage(rng: np.random.Generator):
    """A parking level: low ceiling, pillars every 7.5-8.5 m, cars in bays between them, two ramps."""
    height = rng.uniform(2.3, 2.7)
    pitch = rng.uniform(7.5, 8.5)
    nx, ny = int(rng.integers(5, 8)), 3
    half_x, half_y = nx * pitch / 2, ny * pitch / 2 + 3.0
    x_lo, x_hi = -half_x - 5.0, half_x + 12.0  # end walls: a turning space at one end, the ramps at the other
    b = MeshBuilder()
    b.add(box([0, 0, -0.3], (2 * half_x + 40, 2 * half_y + 30, 0.3)), 0.25)
    b.add(box([0, 0, height], (2 * half_x + 40, 2 * half_y + 30, 0.4)), 0.45)
    for sgn in (-1, 1):
        b.add(box([0.5 * (x_lo + x_hi), sgn * (half_y + 0.15), 0], (x_hi - x_lo + 0.6, 0.3, height)), 0.5)
    for x in (x_lo - 0.15, x_hi + 0.15):
        b.add(box([x, 0, 0], (0.3, 2 * half_y, height)), 0.5)
    xs = -half_x + pitch * np.arange(nx + 1)
    for x in xs:  # pillar rows: two in the middle, one along each long wall
        for y in (-pitch / 2, pitch / 2, -half_y + 0.5, half_y - 0.5):
            b.add(box([x, y, 0], (0.5, 0.5, height)), 0.5)
    for x0 in xs[:-1]:  # bays: three cars nose-in per bay along the walls, one parallel per bay in the middle
        for yc, yaw in ((-half_y + 3.0, np.pi / 2), (half_y - 3.0, -np.pi / 2)):
            for k in range(3):
                if rng.uniform() < 0.7:
                    _car(b, rng, (x0 + pitch * (k + 0.5) / 3, yc), yaw + rng.normal(0, 0.04))
        for yc in (-1.7, 1.7):
            if rng.uniform() < 0.7:
                _car(b, rng, (x0 + pitch / 2, yc), float(rng.choice([0.0, np.pi])) + rng.normal(0, 0.03))
    for sgn in (-1, 1):  # ramps beyond the last pillars: a slab rising from the floor to the next level
        y0 = sgn * (half_y - 4.0)
        ramp = np.array([[[half_x + 1.0, y0 - 1.8, 0.0], [half_x + 1.0, y0 + 1.8, 0.0]],
                         [[x_hi - 0.5, y0 - 1.8, height], [x_hi - 0.5, y0 + 1.8, height]]])
        b.add(strip(ramp), 0.3)
    py = 0.5 * ((pitch / 2 + 0.25) + (half_y - 5.25))  # middle of the aisles between pillars and wall cars
    path = np.array([[-half_x - 2.5, -py], [half_x + 2.0, -py], [half_x + 2.0, py], [-half_x - 2.5, py]])
    return b, path, height


_BUILDERS = {"corridor": corridor, "hall": hall, "courtyard": courtyard, "garage": garage}


def build_place(name: str, seed: int) -> Place:
    """The place ``name`` (one of :data:`PLACES`) for ``seed``; same arguments, same place."""
    if name not in _BUILDERS:
        raise SimulationError(f"unknown place {name!r}; choose one of {', '.join(PLACES)}")
    rng = np.random.default_rng([int(seed), 4243, PLACES.index(name)])
    b, path, ceiling = _BUILDERS[name](rng)
    v, f, a = b.build()
    return Place(name, v, f, a, np.asarray(path, dtype=np.float64), ceiling)
