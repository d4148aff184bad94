"""A tilted scan from outside the map ends its search early (core/tilted_search.py): after an upright round whose
every answer the map verdict calls "not here" (under ``localization.retry_floor``), the levelled round registers only
the places its levelled descriptor matches (under ``retry_descriptor``). A scan of the map tilted alike is placed as
before. The map and queries of test_localization.py (known truth: the simulated drive's poses)."""

from __future__ import annotations

import numpy as np
from test_localization import _ok, localizer, world  # noqa: F401  (fixtures)

from deepbbs_ros.config import Config


def _counted(loc, scan, overrides: dict):
    """``scan`` localized under the config ``overrides``: -> (result, DeepBBS++ calls, GICP-alone calls)."""
    deep, gicp = [], []
    f_deep, f_gicp, old = loc._deep, loc._gicp, loc.config
    mine = {k: loc.__dict__[k] for k in ("_deep", "_gicp") if k in loc.__dict__}  # a caller's own stand-ins
    loc._deep = lambda *a, **k: deep.append(1) or f_deep(*a, **k)
    loc._gicp = lambda *a, **k: gicp.append(1) or f_gicp(*a, **k)
    try:
        loc.config = old.replace(**overrides)
        res = loc.localize(scan)
    finally:
        loc.config = old
        del loc._deep, loc._gicp
        loc.__dict__.update(mine)
    return res, len(deep), len(gicp)


def _roll(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T = np.eye(4)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T


def test_a_tilted_scan_from_elsewhere_is_not_searched_again_levelled(localizer, world):  # noqa: F811
    """Rolled 2 degrees (beyond the ground fit's resolution: the levelled round is asked): a scan of another world,
    every upright answer under retry_floor and no place under retry_descriptor levelled either, gets no pose after the
    upright round alone; retry_descriptor 1 registers the levelled places too. A scan of the map rolled alike is
    placed."""
    _, _, drive, other = world
    tilt = _roll(2.0)
    scan = other.scan_at(3).points @ tilt[:3, :3].T
    assert localizer._levelling(localizer.prepare(scan).pre) is not None
    res, n_deep, _ = _counted(localizer, scan, {})
    slow, n_slow, _ = _counted(localizer, scan, {"localization.retry_descriptor": 1.0})
    top_k = Config().localization.top_k
    assert not res.valid and not slow.valid and n_deep == res.candidates == top_k < n_slow, (n_deep, n_slow)
    k = 48
    res, _, _ = _counted(localizer, drive.scan_at(k).points @ tilt[:3, :3].T, {})
    assert res.valid and _ok(res.T_map_scan, drive.pose_at(k) @ np.linalg.inv(tilt))[0], res.reason

