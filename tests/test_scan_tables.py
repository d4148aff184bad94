"""What the verdict keeps on a scan's precision-stage cloud (core/target_surface.py): its target tables and the spread
subset of its voxels are the same numbers as a fresh computation, shared by the scan's two roles in a stream (source,
then target), and drawn again when the cloud's voxels are replaced."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.core import verdict, visibility
from deepbbs_ros.core.polish import prepare_polish_cloud


def _room(seed: int, n: int = 6000) -> np.ndarray:
    """A box room's walls, floor and ceiling seen from near its middle (N, 3), metres."""
    rng = np.random.default_rng(seed)
    p = rng.uniform([-6, -3, -1], [6, 3, 2], (n, 3))
    face = rng.integers(0, 6, n)
    p[face == 0, 0], p[face == 1, 0], p[face == 2, 1] = -6, 6, -3
    p[face == 3, 1], p[face == 4, 2], p[face == 5, 2] = 3, -1, 2
    return p


def _cloud(seed: int):
    return prepare_polish_cloud(_room(seed), 0.3, 10)


def test_spread_points_is_the_spread_subset_and_kept():
    pc = _cloud(1)
    first = visibility.spread_points(pc, 256, 0.3)
    np.testing.assert_array_equal(first, verdict.spread_subset(pc.points(), 256, 0.3))
    assert visibility.spread_points(pc, 256, 0.3) is first  # the second role's draw: kept
    assert not first.flags.writeable  # shared: no caller may write into it
    other = visibility.spread_points(pc, 128, 0.3)  # another size: drawn, the same as fresh
    np.testing.assert_array_equal(other, verdict.spread_subset(pc.points(), 128, 0.3))


def test_kept_tables_are_fresh_ones_and_redrawn_when_the_voxels_change():
    pc, new = _cloud(2), _cloud(3)
    pts = visibility.spread_points(pc, 256, 0.3)
    tables = visibility._target(pc, 0.5)
    assert visibility._target(pc, 0.5) is tables
    fresh = visibility._target(_cloud(2), 0.5)  # the same scan prepared again
    for a, b in zip(tables, fresh):
        if isinstance(a, tuple):
            for x, y in zip(a, b):
                np.testing.assert_array_equal(x, y)
        else:
            np.testing.assert_array_equal(a, b)
    pc.cloud, pc.tree = new.cloud, new.tree  # the cloud's voxels replaced: nothing kept is read
    np.testing.assert_array_equal(visibility.spread_points(pc, 256, 0.3), verdict.spread_subset(new.points(), 256, 0.3))
    assert not np.array_equal(visibility.spread_points(pc, 256, 0.3), pts)
    np.testing.assert_array_equal(visibility._target(pc, 0.5)[0], new.points())
    np.testing.assert_array_equal(visibility._target(pc, 0.5)[1][1], visibility._target(new, 0.5)[1][1])


@pytest.mark.parametrize("dist", [0.5, 0.3])
def test_a_stream_scans_verdict_is_the_fresh_one(dist):
    """A scan judged as a target after it was a source (its spread subset and tables kept) gets the probability of a
    scan prepared afresh."""
    a, b = _cloud(4), _cloud(5)
    T = np.eye(4)
    T[:3, 3] = [0.05, -0.02, 0.0]
    pts = visibility.spread_points(b, 256, 0.3)
    kept_first = verdict.probability(visibility.spread_points(a, 256, 0.3), T, b, dist, "good_start")  # a: source
    kept = verdict.probability(pts, np.linalg.inv(T), a, dist, "good_start")  # a: the next pair's target
    fresh_a, fresh_b = _cloud(4), _cloud(5)
    assert kept_first == verdict.probability(verdict.spread_subset(fresh_a.points(), 256, 0.3), T, fresh_b, dist,
                                             "good_start")
    assert kept == verdict.probability(verdict.spread_subset(fresh_b.points(), 256, 0.3), np.linalg.inv(T), fresh_a,
                                       dist, "good_start")


def test_ready_to_judge_keeps_what_the_verdict_computes():
    """A scan made ready on arrival (the node's registration process) keeps the tables and subset the verdict would
    compute; a scan whose cloud waits for its k-d tree is left as it is."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.scans import prepare_scan, ready_to_judge

    cfg = Config()
    rc = cfg.registration
    pre = ready_to_judge(cfg, prepare_scan(cfg, _room(6).astype(np.float32), lazy=True))
    pc = pre.polish_cloud
    kept = (pc._visibility[1], pc._spread[2])
    fresh = prepare_scan(cfg, _room(6).astype(np.float32), lazy=True).polish_cloud
    assert visibility._target(pc, rc.verdict_dist) is kept[0]
    np.testing.assert_array_equal(kept[0][1][1], visibility._target(fresh, rc.verdict_dist)[1][1])
    assert visibility.spread_points(pc, rc.good_start_points, rc.polish_voxel) is kept[1]
    np.testing.assert_array_equal(kept[1], verdict.spread_subset(fresh.points(), rc.good_start_points, rc.polish_voxel))
    waiting = ready_to_judge(cfg, prepare_scan(cfg, _room(6).astype(np.float32), defer=True, lazy=True)).polish_cloud
    assert not hasattr(waiting, "_visibility") and not hasattr(waiting, "_spread")


def test_the_registration_process_readies_a_streams_source_once_answered():
    """node/registration_worker.py: once a pair is answered, its source is made ready to judge when the pair's target
    was an earlier pair's source (one stream: it is the next target); two sensors' scans (a target never a source)
    are left as they are."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.scans import prepare_scan
    from deepbbs_ros.node.registration_worker import _Worker

    cfg = Config()
    reg = type("Reg", (), {"config": cfg})()
    worker = _Worker(None, reg)
    pres = {k: prepare_scan(cfg, _room(10 + k).astype(np.float32), lazy=True) for k in range(4)}
    for k, pre in pres.items():
        worker.put(k, pre)
    worker.answered(("register", 1, 0, None, True))  # the first pair: its target was no source
    assert not hasattr(pres[1].polish_cloud, "_visibility")
    worker.answered(("register", 2, 1, None, True))  # scan 2 against scan 1, the last source: a stream
    kept = pres[2].polish_cloud._visibility[1]
    np.testing.assert_array_equal(kept[0], pres[2].polish_cloud.points())
    assert visibility.spread_points(pres[2].polish_cloud, cfg.registration.good_start_points,
                                    cfg.registration.polish_voxel) is pres[2].polish_cloud._spread[2]
    worker.answered(("register", 3, 0, None, True))  # another sensor's scan as the target: nothing built
    assert not hasattr(pres[3].polish_cloud, "_visibility")
