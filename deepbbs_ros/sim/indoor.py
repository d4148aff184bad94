"""Indoor places: an office corridor loop and a hall (no ROS).

Both have a floor at z = 0, walls all round and a ceiling, so every ray a sensor casts upwards hits
something (no open sky). Each builder returns ``(MeshBuilder, path (K, 2), ceiling height)``; the path
is a closed loop of waypoints kept at least 1 m from any wall or object, which the mounts follow.
"""

from __future__ import annotations

import numpy as np

from deepbbs_ros.sim.geometry import MeshBuilder, box, cylinder

ALB_FLOOR, ALB_WALL, ALB_CEIL, ALB_DOOR = 0.3, 0.6, 0.7, 0.45


def _wall_x(b: MeshBuilder, x0: float, x1: float, y: float, height: float, rng, doors: bool, side: int) -> None:
    """A wall along x at ``y`` (0.2 m thick) from x0 to x1, with door recesses every 4-9 m when ``doors``.

    A door is a 0.9-1.0 m gap closed by a panel 0.15 m behind the wall (on the wall's ``side``, +-1,
    away from the corridor), 2.1 m high with the wall continuing above it.
    """
    x = x0
    while x < x1:
        gap_at = x + rng.uniform(4.0, 9.0) if doors else x1
        seg_end = min(gap_at, x1)
        if seg_end - x > 0.05:
            b.add(box([0.5 * (x + seg_end), y, 0.0], (seg_end - x, 0.2, height)), ALB_WALL)
        if seg_end >= x1:
            break
        w = rng.uniform(0.9, 1.0)
        w = min(w, x1 - seg_end)
        b.add(box([seg_end + 0.5 * w, y, 2.1], (w, 0.2, height - 2.1)), ALB_WALL)  # lintel
        b.add(box([seg_end + 0.5 * w, y + side * 0.15, 0.0], (w, 0.05, 2.1)), ALB_DOOR)
        x = seg_end + w


def _rotated(b_src: MeshBuilder, b_dst: MeshBuilder) -> None:
    """Copy ``b_src``'s triangles into ``b_dst`` turned 90 deg about z (x -> y)."""
    v, f, a = b_src.build()
    if len(f):
        b_dst.add((v[:, [1, 0, 2]] * [-1, 1, 1], f), a)


def corridor(rng: np.random.Generator):
    """A rectangular corridor loop (2-3 m wide, 2.6-3.2 m high) round a block of rooms, doors on both
    sides, cabinets and bins along the walls, ceiling lights."""
    half_x, half_y = rng.uniform(15.0, 25.0), rng.uniform(9.0, 15.0)
    width, height = rng.uniform(2.0, 3.0), rng.uniform(2.6, 3.2)
    b = MeshBuilder()
    b.add(box([0, 0, -0.3], (2 * half_x + 2, 2 * half_y + 2, 0.3)), ALB_FLOOR)
    b.add(box([0, 0, height], (2 * half_x + 2, 2 * half_y + 2, 0.3)), ALB_CEIL)
    by = MeshBuilder()  # the walls along y, built along x and turned
    for sgn in (-1, 1):  # outer walls (doors outwards) and inner walls (doors into the central rooms)
        _wall_x(b, -half_x - 0.2, half_x + 0.2, sgn * (half_y + 0.1), height, rng, True, sgn)
        _wall_x(b, -half_x + width, half_x - width, sgn * (half_y - width - 0.1), height, rng, True, -sgn)
        _wall_x(by, -half_y - 0.2, half_y + 0.2, sgn * (half_x + 0.1), height, rng, True, sgn)
        _wall_x(by, -half_y + width, half_y - width, sgn * (half_x - width - 0.1), height, rng, True, -sgn)
    _rotated(by, b)
    # the central block: a closed box of rooms behind the inner walls
    b.add(box([0, 0, 0], (2 * (half_x - width) - 0.6, 2 * (half_y - width) - 0.6, height)), ALB_WALL)
    for _ in range(int(rng.integers(6, 14))):  # cabinets and bins against the outer walls
        along, sgn = rng.uniform(-half_x + 3, half_x - 3), rng.choice([-1, 1])
        d = rng.uniform(0.3, 0.5)
        b.add(box([along, sgn * (half_y - d / 2), 0], (rng.uniform(0.4, 1.2), d, rng.uniform(0.6, 1.9))), 0.5)
    for x in np.arange(-half_x + 2, half_x - 1, 3.0):  # ceiling lights
        for sgn in (-1, 1):
            b.add(box([x, sgn * (half_y - width / 2), height - 0.06], (1.2, 0.3, 0.06)), 0.9)
    c = width / 2
    path = np.array([[-half_x + c, -half_y + c], [half_x - c, -half_y + c], [half_x - c, half_y - c],
                     [-half_x + c, half_y - c]])
    return b, path, height


def hall(rng: np.random.Generator):
    """A hall (15-25 x 20-40 m, 6-10 m high) with a grid of columns, tables, shelves and a mezzanine."""
    half_x, half_y = rng.uniform(10.0, 20.0), rng.uniform(7.5, 12.5)
    height = rng.uniform(6.0, 10.0)
    b = MeshBuilder()
    b.add(box([0, 0, -0.3], (2 * half_x + 2, 2 * half_y + 2, 0.3)), ALB_FLOOR)
    b.add(box([0, 0, height], (2 * half_x + 2, 2 * half_y + 2, 0.4)), ALB_CEIL)
    for sgn in (-1, 1):
        b.add(box([0, sgn * (half_y + 0.15), 0], (2 * half_x + 0.6, 0.3, height)), ALB_WALL)
        b.add(box([sgn * (half_x + 0.15), 0, 0], (0.3, 2 * half_y, height)), ALB_WALL)
    step = rng.uniform(6.0, 9.0)
    for x in np.arange(-half_x + step, half_x - 1.0, step):
        for y in (-half_y / 2, half_y / 2):
            b.add(cylinder([x, y, 0], 0.3, height, sides=8), 0.55)
    for _ in range(int(rng.integers(5, 12))):  # tables in the middle band, shelves along the long walls
        b.add(box([rng.uniform(-half_x + 4, half_x - 4), rng.uniform(-1.0, 1.0), 0],
                  (rng.uniform(1.2, 2.5), rng.uniform(0.8, 1.2), 0.75), rng.uniform(0, np.pi)), 0.4)
        sgn = rng.choice([-1, 1])
        b.add(box([rng.uniform(-half_x + 2, half_x - 2), sgn * (half_y - 0.4), 0],
                  (rng.uniform(1.5, 4.0), 0.6, rng.uniform(1.8, 2.6))), 0.35)
    b.add(box([half_x - 3.0, 0, 3.0], (6.0, 2 * half_y, 0.3)), 0.5)  # mezzanine along one end wall
    px, py = half_x - 8.0, half_y / 2 + 2.0  # loop between the columns and the shelves
    path = np.array([[-px, -py], [px, -py], [px, py], [-px, py]])
    return b, path, height
