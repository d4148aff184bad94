"""The verdict's direction tables (core/visibility.py) are computed on a flat table instead of a sort: the same
numbers as the sort they replace, on dense, sparse and edge-of-the-sphere clouds."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.core import visibility


def _angles(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The definition: azimuth, elevation (rad) and range (m) of points (N, 3)."""
    r = np.linalg.norm(p, axis=1)
    return np.arctan2(p[:, 1], p[:, 0]), np.arcsin(np.clip(p[:, 2] / np.maximum(r, 1e-9), -1.0, 1.0)), r


def _keys(az: np.ndarray, el: np.ndarray, cell: float) -> np.ndarray:
    """The definition: the floor of the shifted angles over the cell."""
    return (np.floor((az + np.pi) / cell).astype(np.int64) * 100_000
            + np.floor((el + np.pi / 2) / cell).astype(np.int64))


def _sorted_cell_size(az: np.ndarray, el: np.ndarray) -> float:
    """The definition: the first cell whose occupied cells hold ``_PER_CELL`` returns on average (np.unique)."""
    step = max(1, -(-len(az) // visibility._SHAPE_POINTS))
    az, el = az[::step], el[::step]
    for cell in visibility._CELLS:
        if len(az) and len(az) * step / len(np.unique(_keys(az, el, cell))) >= visibility._PER_CELL:
            return float(cell)
    return float(visibility._CELLS[-1])


def _sorted_directions(target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The definition: the occupied cells' keys sorted, the nearest return in each (argsort and reduceat)."""
    taz, tel, tr = _angles(np.asarray(target, np.float64))
    cell = _sorted_cell_size(taz, tel)
    tkey = _keys(taz, tel, cell)
    order = np.argsort(tkey)
    tkey, tr = tkey[order], tr[order]
    starts = np.flatnonzero(np.r_[True, tkey[1:] != tkey[:-1]])
    return cell, tkey[starts], np.minimum.reduceat(tr, starts)


def _clouds() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    out = []
    for n, el_span in ((60_000, 0.4), (3_000, 0.6), (800, 1.5), (20, 1.5)):  # 64 beams .. a few returns
        az, el = rng.uniform(-np.pi, np.pi, n), rng.uniform(-el_span, el_span, n)
        r = rng.uniform(0.5, 80.0, n)
        out.append(np.c_[r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)])
    edge = np.array([[-1.0, 0.0, 0.0], [-1.0, -1e-12, 0.0], [0.0, 0.0, 5.0], [0.0, 0.0, -5.0], [1.0, 0.0, 0.0],
                     [-3.0, 1e-12, 1.0], [0.0, 0.0, 1e-9]])
    out.append(np.vstack([edge, edge * 2.0, out[2][:30]]))  # azimuth +-pi, straight up and down
    return out


@pytest.mark.parametrize("k", range(5))
def test_direction_tables_are_the_sorted_ones(k):
    target = _clouds()[k]
    cell, keys, nearest = visibility.directions(target)
    ref_cell, ref_keys, ref_nearest = _sorted_directions(target)
    assert cell == ref_cell
    np.testing.assert_array_equal(keys, ref_keys)
    np.testing.assert_array_equal(nearest, ref_nearest)
    taz, tel, _ = visibility._angles(target)
    assert visibility.cell_size(taz, tel) == _sorted_cell_size(taz, tel)


@pytest.mark.parametrize("k", range(5))
def test_angles_and_keys_are_the_definitions_to_the_last_bit(k):
    """The range as three products summed (np.linalg.norm's sums) and the keys as an integer cast of never-negative
    quotients (the floor's): the same numbers, edges of the sphere included."""
    target = _clouds()[k]
    got, want = visibility._angles(target), _angles(target)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)
    for cell in visibility._CELLS:
        np.testing.assert_array_equal(visibility._keys(*got[:2], float(cell)), _keys(*want[:2], float(cell)))
