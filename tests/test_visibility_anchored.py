"""The verdict's ``anchored`` features (core/anchoring.py): is a pose held where it is along the direction its plane
matches pin least? A right pose in a street with cross walls, or on a floor and a wall that end, loses its close
points when moved along that direction; a pose slid along the same planes loses none."""

from __future__ import annotations

import numpy as np
import pytest
from plane_scenes import FLOOR as _FLOOR
from plane_scenes import STREET as _STREET
from plane_scenes import scene as _scene

from deepbbs_ros.config import Config
from deepbbs_ros.core import anchoring, calibrated, verdict, visibility
from deepbbs_ros.core.polish import prepare_polish_cloud
from deepbbs_ros.errors import VerdictModelError

_WALL = [(0, 5.0, (-10, 10), (-1, 2))]
_CORRIDOR = [(0, 2.0, (-60, 60), (-1, 2)), (0, -2.0, (-60, 60), (-1, 2)), (2, -1.0, (-2, 2), (-60, 60))]



def _features(planes, shift: float = 0.0) -> dict[str, float]:
    rc = Config().registration
    target = prepare_polish_cloud(_scene(planes, np.random.default_rng(0), 6000), rc.polish_voxel,
                                  rc.polish_neighbors, threads=1)
    T = np.eye(4)
    T[1, 3] = shift  # along the walls and the floor
    source = _scene(planes, np.random.default_rng(1), 600)
    return dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, rc.verdict_dist), strict=True))


def test_a_right_pose_held_by_where_the_planes_end_is_anchored_a_slid_one_is_not():
    for planes in (_STREET, _WALL + _FLOOR):
        right, slid = _features(planes), _features(planes, 1.5)
        assert slid["pinned"] < 0.05 and right["pinned"] < 0.08, (right, slid)  # pinned barely tells them apart
        assert slid["anchored"] == 0.0 and slid["anchored_far"] == 0.0, slid
        assert right["anchored_far"] > 0.07 and right["anchored"] > 0.02, right
        assert right["anchored_far"] >= right["anchored"], right  # moved further, loses more


def test_a_corridor_with_nothing_along_it_anchors_neither():
    right, slid = _features(_CORRIDOR), _features(_CORRIDOR, 1.5)
    assert right["anchored"] < 0.02 and slid["anchored"] < 0.02, (right, slid)


def test_anchored_of_few_matches_and_without_measuring():
    rng = np.random.default_rng(3)
    assert anchoring.weakest(rng.normal(size=(5, 3)), np.tile([1.0, 0, 0], (5, 1))) is None
    none = np.zeros((5, 3))
    assert anchoring.anchored(none, np.zeros(5), None, none, none, 0.5) == (0.0, 0.0)
    rc = Config().registration
    target = prepare_polish_cloud(_scene(_STREET, rng, 3000), rc.polish_voxel, rc.polish_neighbors, threads=1)
    src = _scene(_STREET, np.random.default_rng(4), 300)
    a = visibility.pose_features(src, np.eye(4), target, rc.verdict_dist)
    b = visibility.pose_features(src, np.eye(4), target, rc.verdict_dist, anchor=False)
    k = visibility.FEATURES.index("anchored")
    assert np.array_equal(a[:k], b[:k]) and list(b[k:]) == [1.0, 1.0]  # the other features are the same
    # the shipped coefficients do not weigh them: the verdict does not measure them
    if not calibrated.weighs(("anchored", "anchored_far"), "good_start"):
        assert verdict.probability(src, np.eye(4), target, rc.verdict_dist, "good_start") == \
            calibrated.probability(b, "good_start")


def test_information_is_the_pinned_units():
    rng = np.random.default_rng(5)
    p = rng.uniform(-5, 5, (300, 3))
    n = rng.normal(size=(300, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    info = anchoring.information(p, n)
    assert np.allclose(info, info.T) and np.all(np.linalg.eigvalsh(info) >= -1e-12)
    s2 = np.linalg.eigvalsh(info)[0]
    assert np.isclose(visibility.pinned(p, n, 0.1), s2 / (s2 + 0.1 * 0.1), rtol=1e-12, atol=0)


def test_the_floor_on_pinned_spares_a_pose_something_else_anchors(tmp_path):
    """With ``min_anchored_far`` the floor on ``pinned`` vetoes only a pose that nothing anchors either."""
    import json

    doc = json.loads(calibrated.DEFAULT_PATH.read_text())
    path = tmp_path / "held.json"
    path.write_text(json.dumps({**doc, "min_pinned": 0.02, "min_anchored_far": 0.05}))
    rows = np.full((3, len(visibility.FEATURES)), 0.95)
    k, h = visibility.FEATURES.index("pinned"), visibility.FEATURES.index("anchored_far")
    rows[:, k] = [0.01, 0.01, 0.03]
    rows[:, h] = [0.04, 0.06, 0.0]
    p = calibrated.probability(rows, "good_start", str(path))
    plain = calibrated.probability(rows, "good_start")
    assert p[0] == 0.0 and p[1] == plain[1] > 0.0 and p[2] == plain[2] > 0.0, (p, plain)
    assert calibrated.min_anchored_far(str(path)) == 0.05 and calibrated.min_anchored_far() == 1.0
    assert calibrated.weighs(("anchored_far",), "good_start", str(path))  # the floor reads it: measured
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**doc, "min_anchored_far": 0.0}))
    with pytest.raises(VerdictModelError, match="min_anchored_far"):
        calibrated.load(str(bad))


def test_the_calibrations_slid_pose_slides_along_the_corridor():
    """scripts/calibrate_verdict.py ``--slid``: the truth moved by k tolerances (0.3 m each) along the direction the
    plane matches pin least; in a corridor that is along its walls, and the slid pose fits as well."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from calibrate_verdict import slid_pose

    rc = Config().registration
    target = prepare_polish_cloud(_scene(_CORRIDOR, np.random.default_rng(0), 6000), rc.polish_voxel,
                                  rc.polish_neighbors, threads=1)
    source = _scene(_CORRIDOR, np.random.default_rng(1), 600)
    T = slid_pose(np.eye(4), source, target, rc.verdict_dist, 3.0)
    assert abs(abs(T[1, 3]) - 0.9) < 0.05 and abs(T[0, 3]) < 0.05 and abs(T[2, 3]) < 0.05, T
    assert np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1))) < 0.3, T
    f = dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, rc.verdict_dist), strict=True))
    right = _features(_CORRIDOR)
    assert f["plane_own"] > right["plane_own"] - 0.05 and f["anchored_far"] < 0.02, (f, right)
    assert slid_pose(np.eye(4), source[:3], target, rc.verdict_dist, 3.0) is None  # too few matches


def test_anchored_far_alone_and_a_settled_side_give_the_same_numbers():
    """``anchored_far`` measured alone (what a bound on ``pinned`` reads) is the pair's second value; a side that keeps
    every close point settles a step at 0 without the other side's search; the k = 1 search's squared distances are
    the nearest-neighbour search's."""
    rc = Config().registration
    dist = rc.verdict_dist
    for planes, shift in ((_STREET, 0.0), (_WALL + _FLOOR, 0.0), (_CORRIDOR, 0.0), (_STREET, 1.5)):
        target = prepare_polish_cloud(_scene(planes, np.random.default_rng(0), 6000), rc.polish_voxel,
                                      rc.polish_neighbors, threads=1)
        T = np.eye(4)
        T[1, 3] = shift
        src = _scene(planes, np.random.default_rng(1), 600)
        moved = src @ T[:3, :3].T + T[:3, 3]
        idx, sq = target.tree.batch_nearest_neighbor_search(moved)
        sq = np.asarray(sq, np.float64)
        assert np.array_equal(anchoring.sq_dists(target.tree, moved), sq)
        nrm = np.asarray(target.cloud.normals())[:, :3][np.asarray(idx, np.int64)]
        tpts = np.asarray(target.cloud.points())[:, :3][np.asarray(idx, np.int64)]
        m = (sq <= dist * dist) & (np.abs(np.einsum("ij,ij->i", moved - tpts, nrm)) <= 0.2 * dist)
        both = anchoring.anchored(moved, sq, target.tree, moved[m], nrm[m], dist)
        far = anchoring.anchored(moved, sq, target.tree, moved[m], nrm[m], dist, steps=anchoring.STEPS[-1:],
                                 info=anchoring.information(moved[m], nrm[m]))
        assert far == both[-1:], (planes, shift)
        close = np.sum(sq <= 0.25 * dist * dist)
        twist = anchoring.weakest(moved[m], nrm[m])
        for k, value in zip(anchoring.STEPS, both):  # both sides searched, as the module says
            kept = [np.sum(anchoring.sq_dists(target.tree, moved @ anchoring._rotation(s * k * twist[3:]).T
                                              + s * k * twist[:3]) <= 0.25 * dist * dist) for s in (1.0, -1.0)]
            assert value == float(np.clip(1.0 - max(kept) / close, 0.0, 1.0)), (planes, shift, k)
        row = visibility.pose_features(src, T, target, dist)
        bounded = visibility.pose_features(src, T, target, dist, anchor=1.0)  # every pose pinned under 1
        k = visibility.FEATURES.index("anchored")
        assert np.array_equal(row[:k], bounded[:k]) and bounded[k] == 1.0 and bounded[k + 1] == row[k + 1]
