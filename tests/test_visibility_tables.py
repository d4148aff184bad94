"""The verdict's direction tables (core/visibility.py) are computed on a flat table instead of a sort: the same
numbers as the sort they replace, on dense, sparse and edge-of-the-sphere clouds."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.core import visibility


def _sorted_cell_size(az: np.ndarray, el: np.ndarray) -> float:
    """The definition: the first cell whose occupied cells hold ``_PER_CELL`` returns on average (np.unique)."""
    step = max(1, -(-len(az) // visibility._SHAPE_POINTS))
    az, el = az[::step], el[::step]
    for cell in visibility._CELLS:
        if len(az) and len(az) * step / len(np.unique(visibility._keys(az, el, cell))) >= visibility._PER_CELL:
            return float(cell)
    return float(visibility._CELLS[-1])


def _sorted_directions(target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The definition: the occupied cells' keys sorted, the nearest return in each (argsort and reduceat)."""
    taz, tel, tr = visibility._angles(np.asarray(target, np.float64))
    cell = _sorted_cell_size(taz, tel)
    tkey = visibility._keys(taz, tel, cell)
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
