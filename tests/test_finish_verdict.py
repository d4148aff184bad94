"""core/finish_verdict.py: a pose finished on the scene-sized grids, judged on both grids where GICP's 0.5 m grid
does not hold it (a narrow corridor's roll about its axis)."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import anchoring, calibrated, finish_verdict, second_minimum, verdict, visibility
from deepbbs_ros.core.good_start import from_start, good_start_points
from deepbbs_ros.core.polish import finish
from deepbbs_ros.metrics import pair_errors


def _corridor_pair(start: int):
    """A simulated Mid-360 carried along a 2-3 m corridor (exact truth): its scans 1 m apart from frame `start` as
    (source, target, T_target_source)."""
    from deepbbs_ros.sim.rig import make_simulator

    sim = make_simulator("corridor", 4, "mid360", "handheld", frames=60, compensate=True)
    (tgt, T_w_t), (src, T_w_s) = [(sim.scan_at(k).points, sim.pose_at(k))
                                  for k in sim.frames_apart(1.0, 2, start=start)]
    return src, tgt, np.linalg.inv(T_w_t) @ T_w_s


def _registration(**settings):
    """The registration in this process with exact GICP and the given registration settings."""
    from deepbbs_ros.core.registration import DeepBBSRegistration

    return DeepBBSRegistration(Config().replace(**{"registration.network_process": "off",
                                                   "registration.exact_gicp": True,
                                                   **{f"registration.{k}": v for k, v in settings.items()}}))


def _good_start_attempt(**settings):
    """The good start's attempt on the corridor pair from frame 30, from identity, and the pair's truth."""
    import torch

    from deepbbs_ros.core import good_start
    from deepbbs_ros.core.network_output import Clock

    src, tgt, T_gt = _corridor_pair(30)
    reg = _registration(**settings)
    try:
        return good_start.attempt(reg, src, tgt, np.eye(4), False, Clock(torch.device("cpu"))), T_gt
    finally:
        reg.close()


@pytest.fixture(scope="module")
def corridor():
    """The corridor pairs from frame 10 and 30, their precision-stage clouds, the good start's points, GICP from
    identity finished on the scene's grids."""
    reg = _registration()
    rc, out = reg.config.registration, {}
    try:
        for start in (10, 30):
            src, tgt, T_gt = _corridor_pair(start)
            spc, tpc = (reg.preprocess(p, lazy=True).polish_cloud.complete(1) for p in (src, tgt))
            fine = finish(spc, tpc, from_start(spc, tpc, np.eye(4), rc).T_target_source, rc)
            out[start] = (T_gt, spc, tpc, good_start_points(spc, rc), fine.T_target_source)
    finally:
        reg.close()
    return rc, out


@pytest.mark.parametrize("start", [10, 30])
def test_a_right_pose_that_gicps_grid_leaves_free_is_taken_on_both_grids(corridor, start):
    """GICP's grid reads the finished right pose as free by over 10 tolerances along a roll about the corridor's axis
    (pinned under the verdict file's held_pinned) and rejects it; read on the scene's grids the roll is pinned, and
    both grids take it."""
    rc, pairs = corridor
    T_gt, spc, tpc, pts, T = pairs[start]
    rot, trans = pair_errors(T, T_gt)
    assert rot < 1.0 and trans < 0.3, (rot, trans)  # right
    f = visibility.pose_features(pts, T, tpc, rc.verdict_dist, 1, True, True)
    assert calibrated.probability(f, "good_start") < rc.good_start_probability
    assert f[visibility.FEATURES.index("pinned")] < calibrated.anchored_below()
    twist, unc = second_minimum.weakest(pts @ T[:3, :3].T + T[:3, 3], tpc, rc.verdict_dist)
    assert unc > 7 and np.argmax(np.abs(twist / anchoring.SCALE)) == 3  # a roll (about x, the walking direction)
    prob, why = finish_verdict.judge(pts, T, spc, tpc, rc, rc.good_start_probability)
    assert why == "" and prob >= rc.good_start_probability, (prob, why)


@pytest.mark.parametrize("move", ["slid 0.6 m", "rolled 3 deg", "rolled -3 deg"])
def test_the_right_pose_moved_along_the_corridor_or_its_roll_is_not_taken(corridor, move):
    """The same right pose slid 0.6 m along the walking direction, or rolled 3 degrees about the direction GICP's grid
    leaves free: wrong, and not taken (the scene's grids pin both)."""
    rc, pairs = corridor
    T_gt, spc, tpc, pts, T = pairs[30]
    D = np.eye(4)
    if move.startswith("slid"):
        D[:3, 3] = 0.6 * T_gt[:3, 3] / np.linalg.norm(T_gt[:3, 3])
    else:
        twist, _ = second_minimum.weakest(pts @ T[:3, :3].T + T[:3, 3], tpc, rc.verdict_dist)
        D[:3, :3] = anchoring._rotation(float(move.split()[1]) * twist[3:] / np.linalg.norm(twist[3:] / np.radians(1)))
    T2 = D @ T
    rot, trans = pair_errors(T2, T_gt)
    assert rot > 2.0 or trans > 0.5, (rot, trans)  # wrong
    prob, why = finish_verdict.judge(pts, T2, spc, tpc, rc, rc.good_start_probability)
    assert why and prob < rc.good_start_probability, (prob, why)


def test_a_pose_gicps_grid_holds_is_judged_there_alone(monkeypatch):
    """Where GICP's grid holds the pose (pinned at least held_pinned), its rejection stands: the scene's grids are not
    read (a pose slid along a corridor whose door frames pin it elsewhere)."""
    rc = Config().registration
    monkeypatch.setattr(visibility, "pose_features", lambda *a, **k: np.r_[np.full(10, 0.5), 0.5, np.full(4, 0.5)])
    monkeypatch.setattr(calibrated, "probability", lambda f, m: 0.1)

    def scene(*a):
        raise AssertionError("the scene's grids read")

    monkeypatch.setattr(verdict, "on_scene_grid", scene)
    prob, why = finish_verdict.judge(np.zeros((10, 3)), np.eye(4), None, None, rc, 0.7)
    assert prob == pytest.approx(0.1) and why.startswith("GICP's grid holds it"), why


def test_the_good_start_takes_the_finished_pose_on_both_grids_where_asked():
    """registration.good_start_finish_grid "both": the good start takes that corridor pair's finished right pose on
    GICP's path; "gicp" (the default) rejects it there, and answers it not valid, degenerate along the roll."""
    for grid in ("gicp", "both"):
        a, T_gt = _good_start_attempt(good_start_finish_grid=grid)
        if grid == "gicp":  # not taken: answered at once, not valid (registration.good_start_degenerate)
            assert a.result is not None and not a.result.valid, a.reason
            assert a.reason.startswith("not valid: degenerate along a roll about x"), a.reason
        else:
            assert a.result is not None and "scene's grid" in a.reason, a.reason
            rot, trans = pair_errors(a.result.T_target_source, T_gt)
            assert rot < 1.0 and trans < 0.3, (rot, trans)


def test_a_degenerate_pose_is_named_and_one_gicps_grid_takes_is_not(corridor):
    """core/finish_verdict.py degenerate: the corridor's finished right pose, which GICP's grid neither holds nor takes
    and takes with pinned read on the scene's grids, is degenerate along a roll about the corridor's axis. A box
    corridor with an end wall and noiseless surfaces, whose right pose GICP's grid takes, is not."""
    from deepbbs_ros.core.registration import DeepBBSRegistration

    rc, pairs = corridor
    T_gt, spc, tpc, pts, T = pairs[30]
    why = finish_verdict.degenerate(pts, T, spc, tpc, rc, rc.good_start_probability)
    assert why.startswith("not valid: degenerate along a roll about x"), why
    rng = np.random.default_rng(0)
    n = 30000
    k = rng.integers(0, 5, n)
    x, y, z = rng.uniform(-12, 6, n), rng.uniform(-1.2, 1.2, n), rng.uniform(-1.0, 1.6, n)
    y = np.where(k == 0, -1.2, np.where(k == 1, 1.2, y))
    z = np.where(k == 2, -1.0, np.where(k == 3, 1.6, z))
    box = np.c_[np.where(k == 4, 6.0, x), y, z]
    T_box = np.eye(4)
    T_box[0, 3] = 0.8
    reg = DeepBBSRegistration(Config().replace(**{"registration.network_process": "off"}))
    try:
        src = (box + rng.normal(0, 0.01, box.shape) - T_box[:3, 3]).astype(np.float32)  # seen 0.8 m further along
        s_pc, t_pc = (reg.preprocess(p, lazy=True).polish_cloud.complete(1) for p in (src, box.astype(np.float32)))
    finally:
        reg.close()
    assert finish_verdict.degenerate(good_start_points(s_pc, rc), T_box, s_pc, t_pc, rc, 0.7) == ""


def test_the_good_start_searches_where_asked_not_to_stop_at_a_degenerate_pose():
    """registration.good_start_degenerate false: the corridor pair's good start goes on to the full pipeline."""
    a, _ = _good_start_attempt(good_start_degenerate=False)
    assert a.result is None and "coarse to fine" in a.reason, a.reason


@pytest.mark.parametrize("grid", ["gicp", "both"])
def test_the_pipelines_finished_answer_is_judged_on_both_grids_where_asked(grid):
    """registration.finish_grid: the full pipeline's right answer to that corridor pair, finished on the scene's grids,
    is rejected on GICP's grid ("gicp", the default) and taken on both ("both")."""
    src, tgt, T_gt = _corridor_pair(30)
    reg = _registration(finish_grid=grid)
    try:
        res = reg.register(src, tgt)
    finally:
        reg.close()
    rot, trans = pair_errors(res.T_target_source, T_gt)
    assert rot < 1.0 and trans < 0.3, (rot, trans)
    assert res.valid == (grid == "both"), res.probability
