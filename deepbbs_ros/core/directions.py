"""Direction cells of a target cloud (no ROS): azimuth x elevation cells sized from the cloud's own angular density
(a 64-beam ring, a 16-beam ring and a Livox rosette get cells holding a few returns each), the nearest return in each,
and the share of moved points whose direction falls in the target's field of view. The tables core/visibility.py's
features read: a point clearly in front of its cell's nearest return is in space the target sensor saw through.
"""

from __future__ import annotations

import numpy as np

_CELLS = np.radians([0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0])  # rad; the direction cells to choose from
_SHAPE_POINTS = 4000  # the cell size is chosen on an even subsample of the target of at most this many points
_PER_CELL = 3.0  # target returns a direction cell should hold on average
_VIEW_CELL = np.radians(5.0)  # rad; ``in_view``'s direction cells: the target's field of view at this resolution


def _cell_table(az: np.ndarray, el: np.ndarray) -> tuple[float, tuple | None]:
    """:func:`cell_size`, and the :func:`_occupied` table of the cell chosen when it was computed on every direction
    (no subsample: then :func:`directions` reuses it), else None. A subsample of every ``step``-th direction with
    ``step >= _PER_CELL`` takes the first cell without a table: its cells hold at least ``step`` returns each."""
    step = max(1, -(-len(az) // _SHAPE_POINTS))
    if len(az) and step >= _PER_CELL:
        return float(_CELLS[0]), None
    az, el = az[::step], el[::step]
    if not len(az):
        return float(_CELLS[-1]), None
    # every cell's _occupied table at once, side by side in one array (the same keys: the same operations)
    i = ((az + np.pi) / _CELLS[:, None]).astype(np.int64)  # :func:`_keys`' cells (never negative: no floor needed)
    j = ((el + np.pi / 2) / _CELLS[:, None]).astype(np.int64)
    i0, j0 = i.min(axis=1), j.min(axis=1)
    rows = j.max(axis=1) - j0 + 1
    sizes = (i.max(axis=1) - i0 + 1) * rows
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    i *= rows[:, None]  # in place: each cell's table index (i - i0) * rows + j - j0, offset by its table's start
    i += j
    i += (starts - i0 * rows - j0)[:, None]
    tables = np.zeros(int(sizes.sum()), bool)
    tables[i.ravel()] = True
    for k, cell in enumerate(_CELLS):
        table = tables[starts[k]:starts[k] + sizes[k]]
        if len(az) * step / np.count_nonzero(table) >= _PER_CELL or k == len(_CELLS) - 1:
            return float(cell), (table, i[k] - starts[k], int(rows[k]), int(i0[k]), int(j0[k])) if step == 1 else None


def _angles(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth, elevation (rad) and range (m) of points (N, 3); the range is np.linalg.norm's to the last bit (the
    same products, summed in the same order) in a sixth of its time."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    r = np.sqrt(x * x + y * y + z * z)
    az = np.arctan2(y, x)
    el = np.arcsin(np.clip(z / np.maximum(r, 1e-9), -1.0, 1.0))
    return az, el, r


def _keys(az: np.ndarray, el: np.ndarray, cell: float) -> np.ndarray:
    """Direction cell keys ``i * 100_000 + j`` of azimuths ``az`` and elevations ``el`` (rad, :func:`_angles`) on a
    ``cell`` rad grid: ``az + pi`` and ``el + pi / 2`` are never negative, so the integer cast is the floor."""
    i = ((az + np.pi) / cell).astype(np.int64)
    j = ((el + np.pi / 2) / cell).astype(np.int64)
    return i * 100_000 + j


def cell_size(az: np.ndarray, el: np.ndarray) -> float:
    """The smallest direction cell (rad) of :data:`_CELLS` in which the target's occupied cells hold about
    ``_PER_CELL`` returns on average (measured on an even subsample of at most ``_SHAPE_POINTS``)."""
    return _cell_table(az, el)[0]


def _occupied(az: np.ndarray, el: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """The direction cells of a ``cell`` rad grid, over the span of directions the target has, as a flat table (no
    sort: a few tens of thousands of bytes for a spinning sensor's 30-degree band at 0.5 degrees): (True where a
    direction falls (the table), each direction's index in it, the elevation cells per azimuth cell (``rows``), the
    first azimuth cell ``i0``, the first elevation cell ``j0``); index ``k`` is :func:`_keys`'
    ``(k // rows + i0) * 100_000 + k % rows + j0``, in the same order."""
    if not len(az):
        return np.zeros(0, bool), np.zeros(0, np.int64), 1, 0, 0
    i = ((az + np.pi) / cell).astype(np.int64)
    j = ((el + np.pi / 2) / cell).astype(np.int64)
    i0, j0 = int(i.min()), int(j.min())
    rows = int(j.max()) - j0 + 1
    table = np.zeros((int(i.max()) - i0 + 1) * rows, bool)
    i *= rows  # in place: the index (i - i0) * rows + j - j0
    i += j
    i -= i0 * rows + j0
    table[i] = True
    return table, i, rows, i0, j0


def directions(target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The target's direction cells: (cell size (rad), the occupied cells' keys (sorted), the nearest return's range
    in each (m))."""
    taz, tel, tr = _angles(np.asarray(target, np.float64))
    cell, occupied = _cell_table(taz, tel)
    table, idx, rows, i0, j0 = _occupied(taz, tel, cell) if occupied is None else occupied
    nearest = np.full(len(table), np.inf)
    np.minimum.at(nearest, idx, tr)
    occupied = np.flatnonzero(table)  # in the order of _keys: the same sorted keys as a sort of them
    return cell, (occupied // rows + i0) * 100_000 + occupied % rows + j0, nearest[occupied]


_VIEW: tuple = (None, 0.0, np.zeros(0, bool))  # (a target's direction keys, their cell, :func:`in_view`'s table)


def in_view(moved: np.ndarray, cell: float, ukey: np.ndarray, keys: np.ndarray | None = None) -> float:
    """The share of ``moved`` (N, 3) (the target's sensor frame) whose direction falls in the target's field of view:
    the :data:`_VIEW_CELL` direction cells (a whole multiple of ``cell``) holding a target return, from the target's
    :func:`directions` keys ``ukey`` (``cell`` rad). Measured on the target's returns (no sensor's constants): a
    70-degree view turned by 35 degrees keeps about half of the source in it, a 360-degree one all of it. ``keys``:
    the points' :func:`_keys` on the ``cell`` grid, when the caller has them."""
    if len(moved) == 0 or len(ukey) == 0 or cell <= 0:
        return 0.0
    global _VIEW
    f = max(1, int(round(_VIEW_CELL / cell)))
    rows = int(np.pi / cell) // f + 2  # the coarse cells as a flat table (no sort), as :func:`_occupied`
    kept = _VIEW  # the last target's table (a target is judged several times in a row); one assignment below
    if kept[0] is not ukey or kept[1] != cell:
        table = np.zeros((int(2 * np.pi / cell) // f + 2) * rows, bool)
        table[(ukey // 100_000 // f) * rows + ukey % 100_000 // f] = True
        kept = _VIEW = (ukey, cell, table)
    table = kept[2]
    if keys is None:
        az, el, _ = _angles(np.asarray(moved, np.float64))
        keys = _keys(az, el, cell)
    return float(np.mean(table[(keys // 100_000 // f) * rows + keys % 100_000 // f]))
