"""The global search's first round ends early once the map verdict is sure of a place: only look-alike places are
registered after it."""

from __future__ import annotations

import numpy as np
from test_localization import _quick_then_slow, localizer, world  # noqa: F401  (fixtures)


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
