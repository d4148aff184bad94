"""The global search's first round ends early: a scan from elsewhere after the candidate that says so, an in-map scan
once the map verdict is sure of a place (only look-alike places are registered after it)."""

from __future__ import annotations

import numpy as np
from test_localization import _ok, _quick_then_slow, localizer, world  # noqa: F401  (fixtures)


def test_a_scan_from_elsewhere_ends_the_first_round_early(localizer, world):  # noqa: F811
    """retry_descriptor 0 (the probability alone decides): a scan of another map is 'no pose' after its first
    candidate (DeepBBS++ once); retry_probability 0 registers every candidate and runs every retry."""
    _, _, _, other = world
    ranked = localizer.rank(localizer.describe(other.scan_at(3).points, localizer.description_centres), None,
                            localizer.description_centres)
    res, slow, quick, calls = _quick_then_slow(
        localizer, other.scan_at(3).points, {"localization.retry_descriptor": 0.0},
        {"localization.retry_probability": 0.0})
    assert len(ranked) > 1
    assert not res.valid and "scan outside the map" in res.reason and res.probability < 0.05, res.reason
    assert quick == res.candidates == 1  # the first round ended at its first candidate
    assert not slow.valid and slow.candidates == len(ranked) and len(calls) > quick + slow.candidates


def test_the_early_end_still_places_an_in_map_scan(localizer, world):  # noqa: F811
    _, _, drive, _ = world
    res = localizer.localize(drive.scan_at(50).points)
    assert res.valid and _ok(res.T_map_scan, drive.pose_at(50))[0], res.reason


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
