"""The global search's first round ends early once the map verdict is sure of a place: only look-alike places are
registered after it."""

from __future__ import annotations

import numpy as np
from test_localization import _quick_then_slow, localizer, world  # noqa: F401  (fixtures)

from deepbbs_ros.config import Config
from deepbbs_ros.metrics import pair_errors


def test_a_sure_answer_registers_only_look_alike_places_after_it(localizer, world):  # noqa: F811
    """No answer scores confident_score 1: a first answer the verdict is sure of (registration.verdict_sure) ends the
    round where the next places look less alike than descriptor_margin; verdict_sure 1 registers them all, for the
    same pose."""
    _, _, drive, _ = world
    scan = drive.scan_at(48).points
    sure, unsure, n_sure, calls = _quick_then_slow(
        localizer, scan, {"localization.confident_score": 1.0, "localization.descriptor_margin": 0.0},
        {"localization.confident_score": 1.0, "localization.descriptor_margin": 0.0,
         "registration.verdict_sure": 1.0})
    assert sure.valid and unsure.valid and sure.probability >= 0.95, (sure.reason, sure.probability)
    assert n_sure == sure.candidates == 1 < unsure.candidates == len(calls) - n_sure
    assert np.allclose(sure.T_map_scan, unsure.T_map_scan, atol=1e-6)


def _gicps(loc, scan, overrides: dict, monkeypatch):
    """``scan`` localized under the config ``overrides``, every GICP of the search recorded: -> (result, the
    PolishResults of the candidates' GICP, DeepBBS++'s precision stage and GICP alone)."""
    from deepbbs_ros.core import place_probe, place_retry, registration_precision

    seen = []
    for mod in (place_retry, place_probe, registration_precision):
        def rec(*a, _f=mod.polish, **k):
            r = _f(*a, **k)
            seen.append(r)
            return r
        monkeypatch.setattr(mod, "polish", rec)
    old = loc.config
    try:
        loc.config = old.replace(**overrides)
        res = loc.localize(scan)
    finally:
        loc.config = old
        monkeypatch.undo()
    return res, seen


def test_a_candidate_the_map_verdict_calls_hopeless_stops_its_gicp_at_the_check(localizer, world, monkeypatch):  # noqa: F811
    """localization.polish_check_probability: a candidate's GICP not converged after polish_check_iters whose pose
    there the map verdict gives less than that probability stops there. A scan from another world: no pose either
    way, the judged GICPs stopped at the check, fewer GICP iterations in all; a scan of the map: the same pose."""
    _, _, drive, other = world
    scan = other.scan_at(3).points
    base = {"localization.retry_probability": 0.0}  # every retry: many GICPs on wrong places
    off, off_gicps = _gicps(localizer, scan, {**base, "localization.polish_check_probability": 0.0}, monkeypatch)
    on, on_gicps = _gicps(localizer, scan, {**base, "localization.polish_check_probability": 0.01}, monkeypatch)
    assert not off.valid and not on.valid, (off.reason, on.reason)
    judged = [g for g in on_gicps if "judged hopeless" in g.reason]
    iters = Config().localization.polish_check_iters
    assert judged and all(g.iterations <= iters and not g.applied for g in judged)
    assert not any("judged hopeless" in g.reason for g in off_gicps)
    assert sum(g.iterations for g in on_gicps) < sum(g.iterations for g in off_gicps)
    inside = drive.scan_at(48).points
    a, _ = _gicps(localizer, inside, {"localization.polish_check_probability": 0.0}, monkeypatch)
    b, _ = _gicps(localizer, inside, {"localization.polish_check_probability": 0.01}, monkeypatch)
    assert a.valid and b.valid and np.allclose(a.T_map_scan, b.T_map_scan, atol=1e-6)
    assert pair_errors(b.T_map_scan, drive.pose_at(48))[1] < 0.3


def test_a_coarse_first_leg_keeps_the_pose_and_costs_a_scan_from_elsewhere_less(localizer, world, monkeypatch):  # noqa: F811
    """localization.polish_check_voxels: a candidate GICP's first leg up to its check aligns the scan on a coarser grid.
    A scan from another world: no pose either way, for fewer source points aligned in all (points x iterations); a
    scan of the map: placed at its true pose either way."""
    import small_gicp

    _, _, drive, other = world
    work = []
    align = small_gicp.align

    def counted(tgt_c, src_c, *a, **k):
        res = align(tgt_c, src_c, *a, **k)
        work.append(src_c.size() * max(1, int(res.iterations)))
        return res

    def localized(scan, lead: int):
        work.clear()
        monkeypatch.setattr(small_gicp, "align", counted)
        res, _ = _gicps(localizer, scan, {"localization.polish_check_voxels": lead}, monkeypatch)
        return res, sum(work)

    off, w_off = localized(other.scan_at(3).points, 0)
    on, w_on = localized(other.scan_at(3).points, 2000)
    assert not off.valid and not on.valid, (off.reason, on.reason)
    assert w_on < w_off, (w_on, w_off)
    a, _ = localized(drive.scan_at(48).points, 0)
    b, _ = localized(drive.scan_at(48).points, 2000)
    assert a.valid and b.valid, (a.reason, b.reason)
    for res in (a, b):
        rot, trans = pair_errors(res.T_map_scan, drive.pose_at(48))
        assert rot < 1.0 and trans < 0.3, (rot, trans)
