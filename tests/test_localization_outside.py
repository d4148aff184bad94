"""A scan from outside the map ends its search early (core/place_search.py ``_hopeless``): GICP alone is not tried on
a failed place the map verdict calls "not here" (under ``localization.retry_floor``) whose descriptor does not match
the scan either (``retry_descriptor``). Scans of the map are placed as before. The map and queries of
test_localization.py (known truth: the simulated drive's poses)."""

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


def test_gicp_alone_skips_places_neither_the_verdict_nor_the_descriptor_favours(localizer, world):  # noqa: F811
    """A scan of another world: every first answer under retry_floor and every place's descriptor distance at least
    retry_descriptor: no pose after the first round, with no GICP alone; retry_descriptor 1 (no descriptor is far
    enough) tries GICP alone on every failed place, for the same answer. A scan of the map is placed either way."""
    _, _, drive, other = world
    scan = other.scan_at(3).points
    quick, _, n_quick = _counted(localizer, scan, {})
    slow, _, n_slow = _counted(localizer, scan, {"localization.retry_descriptor": 1.0})
    assert not quick.valid and not slow.valid and "scan outside the map" in quick.reason, quick.reason
    assert quick.probability < 0.01 and n_quick == 0 < n_slow == slow.candidates
    for k in (48, 72):
        res, _, _ = _counted(localizer, drive.scan_at(k).points, {})
        assert res.valid and _ok(res.T_map_scan, drive.pose_at(k))[0], (k, res.reason)



def test_a_scan_of_the_map_whose_network_answers_all_fail_is_placed_by_gicp_alone(localizer, world):  # noqa: F811
    """Every DeepBBS++ answer forced 20 m off (probability about 0, as on real scans whose network passes all went
    astray): the first round calls the scan outside the map, and GICP alone from the descriptor's start places it on
    the places whose descriptor matches it (under retry_descriptor), the well-matching ones not skipped."""
    _, _, drive, _ = world
    k = 48
    deep = localizer._deep

    def astray(src, crop, T_init, place, timings, **kw):
        ans = deep(src, crop, T_init, place, timings, **kw)
        T = ans.T.copy()
        T[:2, 3] += 20.0
        return localizer._answer(0.0, T, place, crop, src)

    localizer._deep = astray
    try:
        c = localizer.description_centres
        dists = [d for _, d, *_ in localizer.rank(localizer.describe(drive.scan_at(k).points, c), None, c)]
        cut = 0.5 * (dists[0] + dists[1])  # the best-ranked place only matches under it
        res, _, n_all = _counted(localizer, drive.scan_at(k).points, {})
        best, _, n_best = _counted(localizer, drive.scan_at(k).points, {"localization.retry_descriptor": cut})
    finally:
        del localizer._deep
    assert dists[0] < Config().localization.retry_descriptor
    for r in (res, best):
        assert r.valid and _ok(r.T_map_scan, drive.pose_at(k))[0], r.reason
    assert n_best < n_all, (n_best, n_all)


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
