"""A scan tilted a little from outside the map ends its search after the upright round (core/tilted_search.py): the
levelled round runs only for a tilt beyond what GICP is trusted to turn a start by
(``registration.good_start_max_rot_deg``). A scan of the map tilted alike is placed as before. The map and queries
of test_localization.py (known truth: the simulated drive's poses)."""

from __future__ import annotations

import numpy as np
from test_localization import _ok, localizer, world  # noqa: F401  (fixtures)


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




def test_a_scan_tilted_within_gicps_reach_is_not_registered_again_levelled(localizer, world):  # noqa: F811
    """Rolled 2 degrees: beyond the ground fit's resolution (the levelled round is asked) but within the registration's
    good-start reach (registration.good_start_max_rot_deg, good_start_max_trans: how far GICP may move a start it is
    trusted from). A scan of the map whose every DeepBBS++ answer goes astray (forced 20 m off, probability about 0, as
    on real scans whose network passes fail): the levelled round does not register again the starts within that reach
    of the upright round's, and GICP alone from the upright starts places the scan; with that reach under its tilt
    the levelled round registers them again, for the same pose."""
    _, _, drive, _ = world
    k, tilt = 48, _roll(2.0)
    scan = drive.scan_at(k).points @ tilt[:3, :3].T
    assert localizer._levelling(localizer.prepare(scan).pre) is not None
    deep = localizer._deep

    def astray(src, crop, T_init, place, timings, **kw):
        ans = deep(src, crop, T_init, place, timings, **kw)
        T = ans.T.copy()
        T[:2, 3] += 20.0
        return localizer._answer(0.0, T, place, crop, src)

    localizer._deep = astray
    try:
        res, n_deep, _ = _counted(localizer, scan, {})
        slow, n_slow, _ = _counted(localizer, scan, {"registration.good_start_max_rot_deg": 1.0})
    finally:
        del localizer._deep
    assert n_deep < n_slow, (n_deep, n_slow)
    truth = drive.pose_at(k) @ np.linalg.inv(tilt)
    for r in (res, slow):
        assert r.valid and _ok(r.T_map_scan, truth)[0], r.reason
