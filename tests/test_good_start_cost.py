"""What the good start reads twice it measures once (core/good_start.py, core/visibility.py): the verdict's features
kept on the target cloud are the features measured afresh, and the verdict's ``pinned`` gives the second-minimum
check's uncertainty along the weakest direction, so a pose held closer than the check looks is not checked again."""

from __future__ import annotations

import numpy as np
from plane_scenes import FLOOR, STREET, scene

from deepbbs_ros.config import Config
from deepbbs_ros.core import second_minimum, verdict, visibility
from deepbbs_ros.core.good_start import good_start_points
from deepbbs_ros.core.polish import prepare_polish_cloud

_PINNED = visibility.FEATURES.index("pinned")


def _clouds(planes, seed: int = 0):
    rc = Config().registration
    target, source = (scene(planes, np.random.default_rng(seed + k), 4000) for k in (0, 1))
    tpc, spc = (prepare_polish_cloud(c, rc.polish_voxel, rc.polish_neighbors, threads=1) for c in (target, source))
    return rc, spc, tpc


def _moved(yaw_deg: float, x: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[0, 3] = x
    return T


def test_the_features_kept_on_the_target_are_the_features_measured_afresh():
    rc, spc, tpc = _clouds(STREET)
    pts = good_start_points(spc, rc)
    for T in (np.eye(4), _moved(1.0, 0.2), _moved(-3.0, 1.5)):
        for anchor, view in ((True, True), (0.02, True), (False, False)):
            first = visibility.pose_features(pts, T, tpc, rc.verdict_dist, 1, anchor, view)
            first[_PINNED] = -1.0  # a caller's change to its copy (core/finish_verdict.py) stays its own
            again = visibility.pose_features(pts, T, tpc, rc.verdict_dist, 1, anchor, view)
            _, _, fresh_tpc = _clouds(STREET)  # the same scans, nothing kept yet
            fresh = visibility.pose_features(pts, T, fresh_tpc, rc.verdict_dist, 1, anchor, view)
            np.testing.assert_array_equal(again, fresh)


def test_pinned_gives_the_second_minimum_checks_uncertainty():
    """``pinned = s^2 / (s^2 + tol^2)`` and the check's uncertainty ``tol / s`` come from the same plane matches: on a
    street (held along every direction but along it) and on a floor alone (free along it and about z)."""
    for planes in (STREET, FLOOR):
        rc, spc, tpc = _clouds(planes)
        pts = good_start_points(spc, rc)
        for T in (np.eye(4), _moved(0.5, 0.1), _moved(2.0, -0.5)):
            pin = float(verdict.features(pts, T, tpc, rc.verdict_dist, "good_start")[_PINNED])
            _, unc = second_minimum.weakest(pts @ T[:3, :3].T + T[:3, 3], tpc, rc.verdict_dist)
            if not np.isfinite(unc) or pin <= 0.0:
                continue
            assert abs(np.sqrt((1.0 - pin) / pin) - unc) <= 1e-9 * max(unc, 1.0), (pin, unc)


def _weakest_afresh(moved: np.ndarray, tpc, dist: float):
    """second_minimum.weakest as it read a scan's cloud before it shared the verdict's search: its own search, the
    cloud's normals copied."""
    idx, sq = tpc.tree.batch_nearest_neighbor_search(moved, num_threads=1)
    idx, sq = np.asarray(idx, np.int64), np.asarray(sq, np.float64)
    normals, tpts = np.asarray(tpc.cloud.normals())[:, :3][idx], np.asarray(tpc.cloud.points())[:, :3][idx]
    plane = np.einsum("ij,ij->i", moved - tpts, normals)
    m = (sq <= dist * dist) & (np.abs(plane) <= 0.2 * dist)
    w, v = np.linalg.eigh(second_minimum.anchoring.information(moved[m], normals[m]))
    s = float(np.sqrt(max(w[0], 0.0)))
    return v[:, 0] * second_minimum.anchoring.SCALE, 0.2 * dist / s, float(np.mean(sq <= dist * dist))


def test_the_checks_weakest_direction_and_fitness_read_the_verdicts_search():
    """The second-minimum check's weakest direction, uncertainty and fitness from the nearest-neighbour search the
    verdict keeps on the target (and its normals) equal those of a search of its own, to 1e-9: on a street and on a
    floor, for poses judged first and poses not judged yet."""
    for planes in (STREET, FLOOR):
        rc, spc, tpc = _clouds(planes)
        pts, d = good_start_points(spc, rc), rc.verdict_dist
        for k, T in enumerate((np.eye(4), _moved(0.5, 0.1), _moved(2.0, -0.5))):
            if k != 1:  # the verdict first: its search and the target's tables kept
                verdict.features(pts, T, tpc, d, "good_start")
            moved = pts @ T[:3, :3].T + T[:3, 3]
            twist, unc = second_minimum.weakest(moved, tpc, d)
            ref_twist, ref_unc, ref_fit = _weakest_afresh(moved, tpc, d)
            assert abs(unc - ref_unc) <= 1e-9 * max(ref_unc, 1.0)
            np.testing.assert_allclose(twist, ref_twist, rtol=0, atol=1e-9)
            assert float(np.mean(visibility._nearest(tpc, moved, 1)[1] <= d * d)) == ref_fit
            assert verdict.fitness(pts, tpc.tree, T, d) == ref_fit


def test_pinned_alone_and_the_finish_verdicts_probability_are_the_full_features():
    """``visibility.pose_pinned`` is ``pose_features``' ``pinned`` (the degenerate judgement reads only that on the
    scene's grids); core/finish_verdict.py's probability from the features the good-start model reads (kept on the
    target) is the one from every feature measured, with and without ``pinned`` replaced."""
    from deepbbs_ros.core import calibrated, finish_verdict

    for planes in (STREET, FLOOR):
        rc, spc, tpc = _clouds(planes)
        pts, d = good_start_points(spc, rc), rc.verdict_dist
        for T in (np.eye(4), _moved(0.5, 0.1), _moved(-3.0, 1.5)):
            _, _, fresh = _clouds(planes)
            pin_alone = visibility.pose_pinned(pts, T, fresh, d)  # before anything is kept on it
            full = visibility.pose_features(pts, T, tpc, d, 1, True, True)
            assert pin_alone == full[_PINNED] == visibility.pose_pinned(pts, T, tpc, d)
            for pinned in (None, 0.3, 0.9):
                f = full.copy()
                if pinned is not None:
                    f[_PINNED] = pinned
                p, own = finish_verdict._probability(pts, T, tpc, d, pinned)
                assert p == float(calibrated.probability(f, "good_start")) and own == full[_PINNED]
