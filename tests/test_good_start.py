"""register(..., good_start=True): GICP alone from a vouched start, a stricter verdict, the full pipeline when it
rejects; the sampling that waits for its first use (PreprocessResult.sample); the path that answered."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from deepbbs_ros.config import Config
from deepbbs_ros.core import verdict
from deepbbs_ros.core.checkpoint import default_weights_path
from deepbbs_ros.core.scans import prepare_scan
from deepbbs_ros.metrics import pair_errors


def _toy_scan(seed: int = 0, n: int = 20000) -> np.ndarray:
    """A road (z = -1.7) with walls and boxes around the sensor: ground and structure."""
    rng = np.random.default_rng(seed)
    road = np.c_[rng.uniform(-40, 40, (n // 2, 2)), np.full(n // 2, -1.7)]
    walls = np.c_[rng.uniform(-40, 40, n // 4), np.where(rng.random(n // 4) < 0.5, -8.0, 8.0),
                  rng.uniform(-1.7, 4.0, n // 4)]
    boxes = rng.normal(0, 1, (n - len(road) - len(walls), 3)) * (1.0, 1.0, 0.8) + rng.choice([-20, -5, 12, 30], (
        n - len(road) - len(walls), 1)) * np.array([1.0, 0.0, 0.0]) + (0.0, 4.0, 0.0)
    return np.vstack([road, walls, boxes]).astype(np.float32)


def test_lazy_sampling_gives_the_eager_numbers():
    """prepare_scan(lazy=True) samples on the first read of a sampled field: the same points as at once, through a
    pickle (the node's registration process) too, and a repr does not run it."""
    cfg, pts = Config(), _toy_scan()
    eager = prepare_scan(cfg, pts)
    lazy = prepare_scan(cfg, pts, lazy=True)
    assert not lazy.sampled and "not sampled yet" in repr(lazy) and not lazy.sampled
    copied = pickle.loads(pickle.dumps(lazy))
    for pre in (lazy, copied):
        np.testing.assert_array_equal(pre.points, eager.points)  # the first read samples
        assert pre.sampled and pre.n_voxels == eager.n_voxels
        np.testing.assert_array_equal(pre.dense_points, eager.dense_points)
        np.testing.assert_allclose(pre.ground_plane, eager.ground_plane)
        assert "sample" in pre.timings_ms and "fps" in pre.timings_ms


def test_lazy_sampling_of_a_sparse_scan_gives_the_eager_numbers():
    """A scan too sparse for the shared grid (a Livox frame, a 16-beam scan in a corridor) is sampled on its own grid:
    with lazy=True that waits too (a good start never pays its ground removal and FPS), with the same numbers."""
    cfg, pts = Config(), _toy_scan(2, n=1500)
    eager = prepare_scan(cfg, pts)
    assert eager.polish_cloud.n_points < 2 * cfg.preprocess.min_candidates  # the scan's own grid
    lazy = prepare_scan(cfg, pts, lazy=True)
    assert not lazy.sampled
    copied = pickle.loads(pickle.dumps(lazy))
    for pre in (lazy, copied):
        np.testing.assert_array_equal(pre.points, eager.points)
        assert pre.sampled and (pre.n_voxels, pre.n_valid, pre.n_input) == (eager.n_voxels, eager.n_valid,
                                                                             eager.n_input)
        np.testing.assert_array_equal(pre.dense_points, eager.dense_points)
        np.testing.assert_allclose(pre.ground_plane, eager.ground_plane)


def test_spread_subset_is_order_independent():
    rng = np.random.default_rng(1)
    pts = np.round(rng.uniform(-50, 50, (5000, 3)) / 0.5) * 0.5 + 0.25  # voxel centroids
    a = verdict.spread_subset(pts, 512, 0.5)
    b = verdict.spread_subset(pts[rng.permutation(len(pts))], 512, 0.5)
    assert 400 < len(a) < 630
    np.testing.assert_array_equal(a[np.lexsort(a.T)], b[np.lexsort(b.T)])
    assert len(verdict.spread_subset(pts[:100], 512, 0.5)) == 100


@pytest.fixture(scope="module")
def drive():
    """An urban corridor (facades on both sides): scans 20 and 21 and the truth T_20_21."""
    if not default_weights_path().is_file():
        pytest.skip("shipped weights missing")
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator("urban", 5, frames=30)
    T_gt = np.linalg.inv(sim.pose_at(20)) @ sim.pose_at(21)
    return sim.scan_at(21).points, sim.scan_at(20).points, T_gt


@pytest.fixture(scope="module")
def reg():
    from deepbbs_ros.core.registration import DeepBBSRegistration

    r = DeepBBSRegistration(Config().replace(**{"registration.network_process": "off"}))
    yield r
    r.close()


def test_good_start_answers_on_the_gicp_path_without_sampling(drive, reg):
    """Consecutive scans from identity and from the truth moved 0.2 m / 1 deg: GICP answers (path "gicp"), within
    tolerance of the truth, and the scans' sampling (ground removal, FPS) never ran."""
    from deepbbs_ros.replay.synthetic import pose

    src, tgt, T_gt = drive
    for T0 in (np.eye(4), T_gt @ pose(0.15, -0.13, 0.0, np.radians(1.0))):
        s, t = reg.preprocess(src, lazy=True), reg.preprocess(tgt, lazy=True)
        res = reg.register(s, t, T_init=T0, good_start=True)
        assert res.path == "gicp" and res.valid and res.good_start == "accepted", res
        assert res.probability >= reg.config.registration.good_start_probability
        rot, tr = pair_errors(res.T_target_source, T_gt)
        assert rot < 0.3 and tr < 0.1, (rot, tr)
        assert not s.sampled and not t.sampled  # ground removal + FPS not paid
        assert res.iterations["deep"] == 0 and "good_start" in res.timings_ms
    plain = reg.register(src, tgt, T_init=np.eye(4))  # without good_start: today's pipeline
    assert plain.path == "deepbbs" and plain.good_start == "" and plain.iterations["deep"] > 0


def test_a_start_slid_along_the_corridor_is_right_or_rejected(drive, reg):
    """Starts slid 4 and 8 m along the road (facades repeat along it), beyond the good start's limits: GICP from the
    start, wherever it ends, is judged by the verdict alone. Either it comes back to the truth and is taken at once
    (path "gicp", named beyond the limits, nothing sampled), or it is turned away and the full pipeline answers on the
    clouds already built; a wrong pose is never accepted."""
    src, tgt, T_gt = drive
    rc = reg.config.registration
    along = T_gt[:3, 3] / np.linalg.norm(T_gt[:3, 3])
    assert rc.good_start_max_trans < 4.0
    for d in (4.0, -8.0):
        T0 = T_gt.copy()
        T0[:3, 3] += d * along
        s, t = reg.preprocess(src, lazy=True), reg.preprocess(tgt, lazy=True)
        res = reg.register(s, t, T_init=T0, good_start=True)
        rot, tr = pair_errors(res.T_target_source, T_gt)
        assert res.timings_ms["good_start"] > 0 and res.timings_ms["total"] >= res.timings_ms["good_start"]
        assert not res.valid or (rot < 1.0 and tr < 0.3), (d, rot, tr, res.good_start)
        if res.path == "gicp":
            assert res.good_start.startswith(("accepted, beyond the good start's limits (GICP from the start: moved",
                                               "accepted after coarse to fine (GICP from")), res.good_start
            assert res.valid and res.probability >= rc.good_start_probability and not s.sampled and not t.sampled
        else:
            assert res.good_start not in ("", "accepted") and "coarse to fine: " in res.good_start, res.good_start
            assert s.sampled and t.sampled  # the fallback sampled the same clouds
        if d == 4.0:  # GICP comes back from 4 m: right, taken on the first try
            assert res.path == "gicp" and rot < 0.3 and tr < 0.1, (rot, tr, res.good_start)


def test_good_start_needs_a_start_and_precision_clouds(drive, reg):
    """No T_init, or preprocessed arrays (no GICP clouds): the full pipeline, as without good_start."""
    src, tgt, _ = drive
    res = reg.register(src, tgt, good_start=True)
    assert res.path == "deepbbs" and res.good_start == ""
    a, b = reg.preprocess(src).points, reg.preprocess(tgt).points
    res = reg.register(a, b, T_init=np.eye(4), preprocessed=True, good_start=True)
    assert res.path == "deepbbs" and res.good_start.startswith("preprocessed arrays")


def test_coarse_to_fine_second_try_stays_within_its_reach():
    """core/coarse_rescue.py: from a start turned 12 degrees and 2.5 m off (outside GICP's fine basin at 10
    iterations) the pyramid then GICP land on the truth, within the reach; from a start turned 30 degrees the truth
    is beyond the reach (2x good_start_max_rot_deg): never taken, whatever GICP finds."""
    from deepbbs_ros.core import coarse_rescue
    from deepbbs_ros.core.registration import good_start_gicp
    from deepbbs_ros.core.scans import polish_cloud
    from deepbbs_ros.replay.synthetic import pose

    cfg = Config()
    rc = cfg.registration
    tgt = _toy_scan(3)
    T_gt = pose(1.0, 0.3, 0.0, np.radians(4.0))  # p_target = R p_source + t
    src = ((tgt - T_gt[:3, 3]) @ T_gt[:3, :3]).astype(np.float32)
    spc, tpc = (polish_cloud(cfg, p).complete(1) for p in (src, tgt))
    assert coarse_rescue.moved(T_gt, T_gt @ pose(3.0, 4.0, 0.0, np.radians(30.0))) == pytest.approx((5.0, 30.0))
    near = T_gt @ pose(2.0, -1.5, 0.0, np.radians(12.0))
    assert not good_start_gicp(spc, tpc, near, rc).applied  # the first try does not converge from there
    pol, why = coarse_rescue.coarse_then_fine(spc, tpc, near, rc, 1)
    assert why == "" and pol.applied, why
    rot, tr = pair_errors(pol.T_target_source, T_gt)
    assert rot < 0.2 and tr < 0.05, (rot, tr)
    far = T_gt @ pose(0.0, 0.0, 0.0, np.radians(30.0))
    pol, why = coarse_rescue.coarse_then_fine(spc, tpc, far, rc, 1)
    assert why != "", pol


def test_the_good_starts_score_and_inlier_ratio_are_the_verdicts_fitness():
    """core/good_start_answer.py scores the good start's answer with one nearest-neighbour search for both shares: the
    same numbers as core.verdict.fitness at registration.verdict_dist and registration.inlier_dist."""
    from deepbbs_ros.core import good_start, good_start_answer
    from deepbbs_ros.core.scans import polish_cloud
    from deepbbs_ros.replay.synthetic import pose

    cfg = Config()
    rc = cfg.registration
    tgt = _toy_scan(4)
    src = _toy_scan(5)
    spc, tpc = (polish_cloud(cfg, p).complete(1) for p in (src, tgt))
    pts = good_start.good_start_points(spc, rc)
    for T in (np.eye(4), pose(0.7, -0.4, 0.1, np.radians(3.0))):
        got = good_start_answer.shares(pts, tpc, T, (rc.verdict_dist, rc.inlier_dist))
        assert got == [verdict.fitness(pts, tpc.tree, T, rc.verdict_dist), verdict.fitness(pts, tpc.tree, T,
                                                                                            rc.inlier_dist)]
    assert good_start_answer.shares(pts[:0], tpc, np.eye(4), (0.5,)) == [0.0]


def test_a_good_start_in_a_box_scene_takes_the_gicp_path_and_is_right(reg):
    """Walls and boxes round the sensor, the source moved 0.8 m and turned 3 degrees: GICP from identity answers
    (path "gicp", accepted on the first try), within 0.2 deg / 0.05 m of the truth, the network never ran."""
    from deepbbs_ros.replay.synthetic import pose

    tgt = _toy_scan(6)
    T_gt = pose(0.8, 0.2, 0.0, np.radians(3.0))
    src = ((tgt - T_gt[:3, 3]) @ T_gt[:3, :3]).astype(np.float32)
    res = reg.register(src, tgt, T_init=np.eye(4), good_start=True)
    assert res.path == "gicp" and res.good_start == "accepted" and res.valid, res
    assert res.iterations["deep"] == 0
    rot, tr = pair_errors(res.T_target_source, T_gt)
    assert rot < 0.2 and tr < 0.05, (rot, tr)


def test_gicp_converged_beyond_the_limits_is_judged_by_the_verdict_alone():
    """GICP from the start converged further than registration.good_start_max_trans, even beyond the coarse try's
    reach (core/coarse_rescue.py REACH times it), or after more than good_start_max_iters iterations: taken on the
    first try when the verdict accepts it (registration.good_start_probability), right, and named beyond the limits."""
    from deepbbs_ros.core import coarse_rescue
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.replay.synthetic import pose

    cfg = Config().replace(**{"registration.network_process": "off", "registration.good_start_max_trans": 0.5})
    reg = DeepBBSRegistration(cfg)
    tgt = _toy_scan(6)
    try:
        for dist in (0.8, 0.5 * coarse_rescue.REACH + 0.3):
            T_gt = pose(dist, 0.0, 0.0, np.radians(1.0))
            src = ((tgt - T_gt[:3, 3]) @ T_gt[:3, :3]).astype(np.float32)
            res = reg.register(src, tgt, T_init=np.eye(4), good_start=True)
            assert res.good_start.startswith("accepted, beyond the good start's limits (GICP from the start: moved "
                                             f"{dist:.2f} m > registration.good_start_max_trans 0.5 m"), res.good_start
            assert res.path == "gicp" and res.valid and res.probability >= cfg.registration.good_start_probability
            rot, tr = pair_errors(res.T_target_source, T_gt)
            assert rot < 0.2 and tr < 0.05, (rot, tr)
    finally:
        reg.close()


def test_a_pose_the_verdict_does_not_take_on_gicps_grid_is_finished_on_the_scenes_grid(monkeypatch):
    """registration.polish_voxel_angle: GICP from the start settles degrees off the truth on its 0.5 m grid in a 2-3 m
    corridor (simulated Mid-360, exact truth); a verdict that takes only poses within 0.3 deg of the truth (patched in)
    rejects it, and the good start finishes it on the scans' scene-sized grids, where it is taken: the answer is GICP's
    path, within 0.2 deg / 5 cm of the truth, and says so. With the verdict taking GICP's pose nothing is finished."""
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.rig import make_simulator

    sim = make_simulator("corridor", 2, make_sensor("mid360", range_noise=0.0, dropout=0.0), "handheld", frames=60,
                         compensate=True, motion_distortion=False)
    (tgt, T_w_t), (src, T_w_s) = [(sim.scan_at(k).points, sim.pose_at(k)) for k in sim.frames_apart(1.0, 2, start=10)]
    T = np.linalg.inv(T_w_t) @ T_w_s
    reg = DeepBBSRegistration(Config().replace(**{"registration.polish_voxel_angle": 0.0625,
                                                  "registration.exact_gicp": True,
                                                  "registration.network_process": "off"}))
    near = {"deg": 0.3}
    monkeypatch.setattr(verdict, "probability",
                        lambda pts, T_est, *a, **k: float(pair_errors(T_est, T)[0] < near["deg"]))
    res = reg.register(src, tgt, T_init=T, good_start=True)
    rot, trans = pair_errors(res.T_target_source, T)
    assert res.path == "gicp" and "scene's grid" in res.good_start, res.good_start
    assert rot < 0.2 and trans < 0.05, (rot, trans)
    near["deg"] = 90.0  # the verdict takes GICP's pose on its own grid: answered as it is, degrees off the truth
    res = reg.register(src, tgt, T_init=T, good_start=True)
    assert res.good_start.startswith("accepted") and "scene's grid" not in res.good_start, res.good_start
    assert pair_errors(res.T_target_source, T)[0] > 1.0



def test_the_finished_pose_can_be_judged_on_the_grid_it_was_finished_on(monkeypatch):
    """registration.good_start_finish_grid "scene": the pose finished on the scans' scene-sized grids is judged on
    those grids (core/verdict.py on_scene_grid: the source's voxels there against the target's finer cloud) with the
    verdict's distance scaled with the finer grid as GICP's correspondence distance is; "gicp" (the default) judges
    it on GICP's grid at registration.verdict_dist. Simulated Mid-360 corridor, exact truth; a verdict that takes
    only poses within 0.3 deg of the truth (patched in) records what it was asked."""
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.rig import make_simulator

    sim = make_simulator("corridor", 2, make_sensor("mid360", range_noise=0.0, dropout=0.0), "handheld", frames=60,
                         compensate=True, motion_distortion=False)
    (tgt, T_w_t), (src, T_w_s) = [(sim.scan_at(k).points, sim.pose_at(k)) for k in sim.frames_apart(1.0, 2, start=10)]
    T = np.linalg.inv(T_w_t) @ T_w_s
    asked = []

    def judge(pts, T_est, target, dist, *a, **k):
        asked.append((getattr(target, "voxel", 0.0), dist))
        return float(pair_errors(T_est, T)[0] < 0.3)

    monkeypatch.setattr(verdict, "probability", judge)
    for grid in ("gicp", "scene"):
        cfg = Config().replace(**{"registration.exact_gicp": True, "registration.network_process": "off",
                                  "registration.good_start_finish_grid": grid})
        rc, reg, asked[:] = cfg.registration, DeepBBSRegistration(cfg), []
        try:
            res = reg.register(src, tgt, T_init=T, good_start=True)
        finally:
            reg.close()
        assert res.path == "gicp" and "scene's grid" in res.good_start, res.good_start
        assert pair_errors(res.T_target_source, T)[0] < 0.2
        (first_grid, first_dist), (grid_m, dist) = asked[0], asked[1]
        assert first_grid == rc.polish_voxel and first_dist == rc.verdict_dist  # GICP's pose on GICP's grid
        if grid == "gicp":
            assert (grid_m, dist) == (rc.polish_voxel, rc.verdict_dist)
        else:  # the finer of the two grids (each about 0.19 m in this 2-3 m corridor), the distance scaled with it
            assert 0.25 * rc.polish_voxel <= grid_m < rc.polish_voxel
            assert dist == pytest.approx(rc.verdict_dist * grid_m / rc.polish_voxel, rel=0.05)


def _corridor(seed: int, end_wall: bool = False, n: int = 12000) -> np.ndarray:
    """A corridor along x (walls at y = +-1.5 m, a floor at z = -1 m, 40 m long): nothing holds x, unless
    ``end_wall`` closes it at x = 12 m."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-20, 20, n)
    k = rng.integers(0, 4 if end_wall else 3, n)
    y = np.where(k == 0, -1.5, np.where(k == 1, 1.5, rng.uniform(-1.5, 1.5, n)))
    z = np.where(k == 2, -1.0, rng.uniform(-1.0, 1.5, n))
    x = np.where(k == 3, 12.0, x)
    return (np.c_[x, y, z] + rng.normal(0, 0.01, (n, 3))).astype(np.float32)


@pytest.mark.parametrize("on", [False, True])
def test_a_start_off_along_a_free_corridor_is_not_taken_with_the_second_minimum_check(on):
    """registration.good_start_second_minimum: a vouched start 1.2 m off along a corridor nothing holds; GICP stays
    there (0.86 m off) and the verdict takes it (off: the hazard); with the check, GICP from that pose moved along its
    weakest direction finds a minimum as good, so the good start does not take it (no result: the full pipeline
    answers). Closed by a wall, the right pose is taken either way."""
    import torch

    from deepbbs_ros.core import good_start
    from deepbbs_ros.core.network_output import Clock
    from deepbbs_ros.core.registration import DeepBBSRegistration

    reg = DeepBBSRegistration(Config().replace(**{"registration.network_process": "off",
                                                  "registration.good_start_second_minimum": on}))
    try:
        T0 = np.eye(4)
        T0[0, 3] = 1.2
        a = good_start.attempt(reg, _corridor(1), _corridor(0), T0, False, Clock(torch.device("cpu")))
        if on:
            assert a.result is None and "a second minimum as good along its weakest direction" in a.reason, a.reason
        else:  # the slid pose taken: what the check is for
            assert a.result is not None and a.result.path == "gicp", a.reason
            assert pair_errors(a.result.T_target_source, np.eye(4))[1] > 0.5
        T0[0, 3] = 0.2
        a = good_start.attempt(reg, _corridor(1, True), _corridor(0, True), T0, False, Clock(torch.device("cpu")))
        assert a.result is not None and a.result.path == "gicp" and a.reason == "accepted", a.reason
        rot, tr = pair_errors(a.result.T_target_source, np.eye(4))
        assert rot < 0.2 and tr < 0.05, (rot, tr)
    finally:
        reg.close()
