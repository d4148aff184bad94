"""The global-localization benchmark's core (scripts/benchmarks/localization.py and its _localization_*.py parts)
on a tiny simulated map.

A small sensor and an 80 m map keep it to seconds; stand-in methods (the truth, a wrong pose, a refusal) check
the bookkeeping against known answers; the real methods are the benchmark's business, not this test's.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import _localization_data as loc_data  # noqa: E402
import _localization_eval as loc_eval  # noqa: E402
import _localization_methods as loc_methods  # noqa: E402
import _localization_scores as loc_scores  # noqa: E402
import _localization_sim as loc_sim  # noqa: E402

from deepbbs_ros.sim import LidarConfig  # noqa: E402


def tiny_args(tmp_path, **kw) -> SimpleNamespace:
    a = dict(map_length=80.0, map_step=4.0, map_range=30.0, map_voxel=0.5, prefixes=[40.0], queries=6, repetitive=2,
             cache=str(tmp_path), baseline_every=2, baseline_timeout=5.0, scaling_queries=2, km_voxel=0.5,
             fpfh_voxel=1.0, grid_places=False, boot_scans=1, boot_step=1.0)
    a.update(kw)
    return SimpleNamespace(**a)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    args = tiny_args(tmp_path_factory.mktemp("loc"))
    lid = LidarConfig(beams=16, azimuth_step_deg=2.0, name="test")
    data = loc_sim.sim_map("suburban", 5, args, log=lambda *_: None, lidar=lid)
    return args, data, lid


def test_map_and_queries_agree_with_the_truth(tiny):
    args, data, lid = tiny
    from scipy.spatial import cKDTree

    assert data.length_m >= 80.0 and len(data.trajectory) >= 15 and len(data.queries) >= 4
    assert {q.kind for q in data.queries} == {"reverse", "lane", "same-lane"}
    assert 40 in data.prefixes and len(data.prefixes[40][0]) < len(data.points)
    tree = cKDTree(data.points)
    for q in data.queries:  # every query, at its true pose, lies on the map built from another drive
        d, _ = tree.query(loc_data.transform(q.points, q.T_map_scan))
        assert np.median(d) < 0.35, (q.kind, q.s, np.median(d))
        # and it is not a scan of the map drive: another lane, or the other way
        near = data.trajectory[np.argmin(np.linalg.norm(data.trajectory[:, :3, 3] - q.T_map_scan[:3, 3], axis=1))]
        off = np.linalg.norm(near[:2, 3] - q.T_map_scan[:2, 3])
        assert off > 0.3 or near[:2, 0] @ q.T_map_scan[:2, 0] < 0
    again = loc_sim.sim_map("suburban", 5, args, log=lambda *_: None, lidar=lid)  # from the cache
    assert np.array_equal(again.points, data.points) and len(again.queries) == len(data.queries)
    assert all(np.array_equal(a.T_map_scan, b.T_map_scan) for a, b in zip(again.queries, data.queries))
    # the boot protocol's next scan: the same drive a second later, on the map too
    assert any(q.follow for q in data.queries)
    for q, a in zip(data.queries, again.queries):
        assert len(q.follow) == len(a.follow) <= 1
        for (dt, pts, T), (_, pts2, T2) in zip(q.follow, a.follow):
            assert dt == 1.0 and np.array_equal(pts, pts2) and np.array_equal(T, T2)
            assert np.linalg.norm(T[:3, 3] - q.T_map_scan[:3, 3]) > 1.0  # it moved on
            d, _ = tree.query(loc_data.transform(pts, T))
            assert np.median(d) < 0.35


def test_bookkeeping_with_known_answers(tiny):
    args, data, _ = tiny
    n = len(data.queries)
    wrong = np.eye(4)
    wrong[0, 3] = 5.0

    class Oracle:  # the truth for the first queries, a wrong pose, then refusals
        build_s = 0.0

        def __init__(self, points, trajectory):
            self.k = 0
            self.by_id = {id(q.points): q for q in data.queries}
            self.by_id.update({id(f[1]): SimpleNamespace(T_map_scan=f[2]) for q in data.queries for f in q.follow})

        def __call__(self, scan):
            q, self.k = self.by_id[id(scan)], self.k + 1
            if self.k == 2:
                return loc_methods.Answer(q.T_map_scan @ wrong, True, "", 0.1)
            if self.k == 3:
                return loc_methods.Answer(None, False, "ambiguous: 2 places", 0.2)
            if self.k == 4:
                return loc_methods.Answer(q.T_map_scan, False, "no candidate passed", 0.3)
            return loc_methods.Answer(q.T_map_scan, True, "", 0.05)

    fig = loc_eval.evaluate_map(data, ["maplocalizer", "kiss-matcher+gicp"], args, log=lambda *_: None,
                             factories={"maplocalizer": Oracle, "kiss-matcher+gicp": Oracle})
    s = fig["methods"]["maplocalizer"]
    assert s["queries"] == n and s["wrong_count"] == 1
    assert s["placed_share"] == pytest.approx((n - 3) / n)
    assert s["ambiguous_share"] == pytest.approx(1 / n) and s["right_but_rejected_share"] == pytest.approx(1 / n)
    assert s["placed_time_s_p50"] == pytest.approx(0.05) and s["placed_rot_err_deg_mean"] < 1e-6
    sub = loc_eval.baseline_subset(n, 2)
    assert fig["methods"]["kiss-matcher+gicp"]["queries"] == len(sub) and n // 3 <= len(sub) <= n // 2 + 1
    assert [r["query"] for r in fig["rows"]["kiss-matcher+gicp"]] == sub
    assert len({loc_data.KINDS[i % 3] for i in loc_eval.baseline_subset(30, 3)}) == 3  # every kind
    assert set(s["by_kind"]) == {"reverse", "lane", "same-lane"}
    assert "baseline_subset" in s and ("repetitive" in s) == any(q.repetitive for q in data.queries)
    sc = fig["scaling"]["by_map_length_m"]
    assert list(sc) == ["40", str(int(round(data.length_m)))]
    assert sc["40"]["map_points"] < sc[list(sc)[-1]]["map_points"]
    pooled = loc_scores.aggregate({"suburban": fig}, ["maplocalizer"])
    assert pooled["maplocalizer"]["sim"]["wrong_count"] == 1
    # the boot protocol: the two refused queries go on with their next scan (the truth now, 1 s after the query, once
    # the search before it has ended); the wrong pose stands, published
    boot = fig["boot_rows"]["maplocalizer"]
    refused = [r for r in fig["rows"]["maplocalizer"] if r["outcome"] == "none"]
    for r in refused:
        b = next(x for x in boot if x["query"] == r["query"])
        if data.queries[r["query"]].follow:
            assert b["outcome"] == "placed" and b["scans"] == 2
            assert b["time_s"] == pytest.approx(max(1.0, r["time_s"]) + 0.05)
        else:
            assert b["outcome"] == "none" and b["scans"] == 1
    booted = sum(bool(data.queries[r["query"]].follow) for r in refused)
    assert s["boot"]["wrong_count"] == 1 and s["boot"]["placed_share"] == pytest.approx((n - 3 + booted) / n)
    assert pooled["maplocalizer"]["sim_boot"]["placed_share"] == s["boot"]["placed_share"]


def test_a_baseline_that_hangs_times_out(tiny):
    args, data, _ = tiny
    slow = loc_methods.Isolated("sleeper", loc_methods._Sleeper, data.points[:10], 0.5, seconds=30.0)
    ans = slow(data.queries[0].points)
    assert ans.timeout and not ans.valid and ans.T_map_scan is None and slow.proc is None  # killed
    row = loc_scores.judge(ans, data.queries[0])
    assert row["outcome"] == "none" and row["timeout"]
    quick = loc_methods.Isolated("sleeper", loc_methods._Sleeper, data.points[:10], 5.0, seconds=0.0)
    ans = quick(data.queries[0].points)
    assert not ans.timeout and ans.valid and np.allclose(ans.T_map_scan, np.eye(4))
    quick.close()


def test_a_baseline_that_raises_answers_no_pose_with_the_error_and_keeps_its_child(tiny):
    args, data, _ = tiny
    broken = loc_methods.Isolated("sleeper", loc_methods._Sleeper, data.points[:10], 5.0, seconds="not a number")
    try:
        ans = broken(data.queries[0].points)
        assert not ans.valid and not ans.timeout and ans.T_map_scan is None
        assert ans.reason.startswith("TypeError") and broken.proc is not None  # the child answers the next query
        assert loc_scores.judge(ans, data.queries[0])["outcome"] == "none"
    finally:
        broken.close()


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs CPU affinity and 2 CPUs")
def test_a_baseline_answers_on_one_cpu_and_is_timed_on_every_core(tiny):
    """The baselines' answers come from a child on one CPU (the same on any machine), their time from a child on
    every core; the every-core call's time limit decides a timeout."""
    args, data, _ = tiny
    both = loc_methods.ExactTimed("sleeper", loc_methods._Sleeper, data.points[:10], 5.0, seconds=0.0)
    try:
        both.start()
        ans = both(data.queries[0].points)
        assert ans.valid and not ans.timeout and ans.reason == "1 cpus" and np.allclose(ans.T_map_scan, np.eye(4))
        assert both.timed(data.queries[0].points).reason == f"{len(os.sched_getaffinity(0))} cpus"
    finally:
        both.close()
    slow = loc_methods.ExactTimed("sleeper", loc_methods._Sleeper, data.points[:10], 0.5, seconds=30.0)
    ans = slow(data.queries[0].points)
    assert ans.timeout and not ans.valid and slow.timed.proc is None and slow.exact.proc is None  # never asked
    slow.close()


def test_maplocalizer_is_timed_as_configured_and_answered_by_its_exact_twin(tiny, monkeypatch):
    """MapLocalizer's query: timed with the config as given (GICP on every core), answered by a twin with
    registration.exact_gicp (the same answer on any machine), whose time is kept beside; --inexact: no twin."""
    from deepbbs_ros.config import Config

    args, data, _ = tiny
    built = []

    class Stub:
        def __init__(self, points, trajectory, config):
            self.exact = config.registration.exact_gicp
            built.append(self.exact)

        def localize(self, scan):
            T = np.eye(4)
            T[0, 3] = 1.0 if self.exact else 2.0
            return SimpleNamespace(T_map_scan=T, valid=self.exact, reason="exact" if self.exact else "timed")

    monkeypatch.setattr(loc_methods.MapLocalizerMethod, "_localizer", staticmethod(Stub))
    monkeypatch.setattr(loc_methods, "_registration", lambda config: None)  # no model to load for the stand-ins
    m = loc_methods.MapLocalizerMethod(data.points, data.trajectory, Config())
    assert built == [False, True]
    ans = m(data.queries[0].points)
    assert ans.valid and ans.reason == "exact" and ans.T_map_scan[0, 3] == 1.0
    assert ans.time_s > 0 and ans.exact_time_s > 0
    s = loc_scores.summarize([dict(loc_scores.judge(ans, data.queries[0]), query=0)])
    assert s["exact_time_s_p50"] == ans.exact_time_s and s["time_s_p50"] == ans.time_s
    alone = loc_methods.MapLocalizerMethod(data.points, data.trajectory, Config(), exact=False)
    ans = alone(data.queries[0].points)
    assert alone.exact is None and ans.reason == "timed" and not np.isfinite(ans.exact_time_s)
