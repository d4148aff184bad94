"""MapTracker on a sensor that stopped or turned back (core/tracking.py, core/guess_tracking.py): the constant-velocity
prediction is then several metres off, and the scan is tracked by GICP from the last pose at rest (the start the scan
fits better, measured on the map), not by the DeepBBS++ path (several scan periods at 10 Hz); a scan that goes on
ahead still starts from the prediction. The map and the drive are tests/test_node_localization.py's."""

from __future__ import annotations

import numpy as np
import pytest
import test_node_localization
from test_node import _check_pose
from test_node_localization import _config, _registration

drive = test_node_localization.drive  # the module fixture: the simulated drive and its map


@pytest.fixture(scope="module")
def tracked(drive):
    """(a MapTracker on the drive's map with its trajectory, the DeepBBS++ registrations counted)."""
    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.tracking import MapTracker

    _, points, poses, _ = drive
    cfg = _config()
    reg = _registration(cfg)
    calls = []
    own = reg.register

    def counted(*args, **kwargs):
        calls.append(1)
        return own(*args, **kwargs)

    reg.register = counted
    return MapTracker(MapLocalizer(points, cfg, registration=reg, trajectory=poses), cfg), calls


@pytest.mark.parametrize("back", [True, False], ids=["turned_back", "went_on"])
def test_turn_back_is_tracked_by_gicp_from_rest(drive, tracked, back):
    """Poses at frames 80 and 82 a period apart (2.3 m a scan), then frame 80's scan (turned back: the prediction,
    ~frame 84, is 4.7 m off, the last pose 2.3 m) or frame 84's (went on): placed right by GICP, no DeepBBS++."""
    sim, _, _, scan = drive
    tracker, calls = tracked
    s0 = sim.stamp_ns(80)
    tracker.reset()
    tracker.state, tracker._poses = "tracking", [(s0, scan(80)[1]), (s0 + 100_000_000, scan(82)[1])]
    k = 80 if back else 84
    pts, T = scan(k)
    off = np.linalg.norm(tracker.predict(s0 + 200_000_000)[:3, 3] - T[:3, 3])
    assert (off > 4.0) if back else (off < 0.5), off
    del calls[:]
    res = tracker.step(pts, s0 + 200_000_000)
    assert res.valid and res.path == "gicp" and not calls, (res.reason, res.path, len(calls))
    _check_pose(res.T_map_scan, T)


def test_tracker_offers_rest_and_the_mirrored_prediction():
    """MapTracker hands the localizer, beside the constant-velocity prediction, the last pose at rest and the prediction
    mirrored (the same step backwards: a sensor that turned back retraces its path), each scaled to the scan's time;
    none after a gap too long for a velocity (the prediction is then the last pose)."""
    from types import SimpleNamespace

    from deepbbs_ros.config import Config
    from deepbbs_ros.core.localization_types import LocalizationResult
    from deepbbs_ros.core.tracking import MapTracker

    seen = []

    def localize(scan, guess, **kw):
        seen.append((guess, kw["starts"]))
        return LocalizationResult(guess, False, float("nan"), "tracking", "test")

    tracker = MapTracker(SimpleNamespace(localize=localize, config=Config()), Config())
    yaw = np.radians(10.0)
    step = np.eye(4)
    step[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    step[:3, 3] = [2.0, 0.5, 0.0]
    T0 = np.eye(4)
    T0[:3, 3] = [5.0, -3.0, 1.0]
    T1 = T0 @ step
    tracker.state, tracker._poses = "tracking", [(0, T0), (100_000_000, T1)]
    tracker.step(np.zeros((10, 3)), 200_000_000)
    guess, starts = seen[-1]
    assert np.allclose(guess, T1 @ step) and len(starts) == 2
    assert np.allclose(starts[0], T1) and np.allclose(starts[1], T0)  # at rest; turned back: the pose a step before
    tracker.state, tracker._poses = "tracking", [(0, T0), (100_000_000, T1)]
    tracker.step(np.zeros((10, 3)), 150_000_000)  # half a period: half a step either way
    guess, starts = seen[-1]
    half_fwd, half_back = np.linalg.inv(T1) @ guess, np.linalg.inv(T1) @ starts[1]
    assert np.allclose(half_fwd @ half_back, np.eye(4), atol=1e-9) and np.allclose(half_fwd[:3, 3] * 2, step[:3, 3],
                                                                                   atol=1e-9)
    tracker.state, tracker._poses = "tracking", [(0, T0), (100_000_000, T1)]
    tracker.step(np.zeros((10, 3)), 100_000_000 + 10 * 100_000_000)  # a gap of ten steps: no velocity
    guess, starts = seen[-1]
    assert np.allclose(guess, T1) and starts == []
