"""scripts/benchmarks/node_latency.py's streams: real KITTI-style scans in the driver layouts the node decodes (the
points come back as they were, the time field of 0 as no times) and the per-period pairs of each stream."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from deepbbs_ros.datasets import write_scans
from deepbbs_ros.datasets.base import Scan
from deepbbs_ros.node.inputs import decode_cloud

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    path = ROOT / "scripts" / "benchmarks" / "node_latency.py"
    spec = importlib.util.spec_from_file_location("bench_node_latency", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        sys.modules.pop(spec.name, None)


def _spinning_scan(index: int, rings: int = 8, per_ring: int = 50) -> Scan:
    """A KITTI-like scan: each laser's points in file order, sweeping the azimuth once (0 to 2 pi)."""
    rng = np.random.default_rng(index)
    az = np.tile(np.linspace(0.01, 2 * np.pi - 0.01, per_ring), rings)
    elev = np.repeat(np.linspace(0.2, -0.4, rings), per_ring)
    r = 10.0 + rng.uniform(0, 5, rings * per_ring)
    xyz = np.stack([r * np.cos(az), r * np.sin(az), r * np.sin(elev)], axis=1).astype(np.float32)
    return Scan(index, index * 100_000_000, xyz, {"intensity": rng.uniform(0, 1, len(xyz)).astype(np.float32)},
                T_world_lidar=np.eye(4))  # fmt: skip


def test_kitti_stream_in_both_driver_layouts(bench, tmp_path):
    scans = [_spinning_scan(i) for i in range(3)]
    write_scans(scans, tmp_path / "seq", "kitti")
    assert bench.kitti_sequences(tmp_path) == [tmp_path / "seq"]
    np.testing.assert_array_equal(bench.kitti_rings(scans[0].points), np.repeat(np.arange(7, -1, -1), 50))
    args = SimpleNamespace()
    for layout in ("velodyne", "ouster"):
        st = bench.kitti_stream(args, layout, "consecutive", tmp_path / "seq")
        assert len(st.msgs) == 3 and st.pairs == [(1, 0), (2, 1), (1, 2), (0, 1)]
        if layout == "ouster":
            assert (st.msgs[0].height, st.msgs[0].width, st.msgs[0].point_step) == (8, 50, 48)
        for msg, scan in zip(st.msgs, scans):
            xyz, times, _, _ = decode_cloud(msg, "/bench", 3)
            assert times is None  # the time field is there, all 0: no per-point times
            key = lambda p: p[np.lexsort(p.T)]  # noqa: E731 - organised rows reorder the points
            np.testing.assert_array_equal(key(xyz), key(scan.points))


def test_stream_pairs(bench):
    assert bench.stream_pairs(4, "consecutive") == [(1, 0), (2, 1), (3, 2), (2, 3), (1, 2), (0, 1)]
    assert bench.stream_pairs(10, "fixed") == [(1, 0), (2, 0), (3, 0), (4, 0), (3, 0), (2, 0)]
    assert bench.stream_pairs(10, "same") == [(1, 0)]
    assert bench.stream_pairs(2, "fixed") == [(1, 0)]


def test_fresh_sources_make_every_period_a_new_scan(bench, tmp_path):
    """Each period's source differs from every earlier one (the node's content-keyed cache must not find a replayed
    frame again) in one point by at most 1 cm; a frame keeps its content until it is published again, so as the
    next period's target it is the cloud just sent; the node's own decoding and cache key see all of that."""
    from deepbbs_ros.node.preprocess_cache import PreprocessCache

    write_scans([_spinning_scan(i) for i in range(2)], tmp_path / "seq", "kitti")
    for layout in ("velodyne", "ouster"):
        msgs = bench.kitti_stream(SimpleNamespace(), layout, "consecutive", tmp_path / "seq").msgs
        before = decode_cloud(msgs[0], "/bench", 3)[0].copy()
        fresh, keys = bench.FreshSources(), set()
        for k in range(6):
            fresh.apply(msgs[0], k)
            xyz = decode_cloud(msgs[0], "/bench", 3)[0]
            moved = np.flatnonzero((xyz != before).any(axis=1))
            assert len(moved) <= 1 and np.abs(xyz - before).max() <= 0.01
            keys.add(PreprocessCache.key(xyz))
            assert PreprocessCache.key(decode_cloud(msgs[0], "/bench", 3)[0]) in keys  # unchanged until applied again
        assert len(keys) == 6, layout


def test_runs_are_kept_and_plotted(bench, tmp_path):
    """--out: one runs.jsonl line per run and node (every pair's latency, period and frames) and latency.png."""
    import json

    r = bench.RunResult(pairs=4, latencies_ms=[80.0, 90.0, 85.0], periods=[0, 1, 3], frames=[(1, 0), (2, 1), (2, 3)],
                        diagnostics={"mode": "pair"}, cpu="CPU ms per period: total 100.0")  # fmt: skip
    recs = bench.save_runs(tmp_path, "velodyne", "consecutive", [("1 (00)", False, {"deepbbs": r})])
    line = json.loads((tmp_path / "runs.jsonl").read_text())
    assert recs == [line] and line["answered"] == 0.75 and line["p50_ms"] == 85.0
    assert line["samples"][2] == {"period": 3, "source": 2, "target": 3, "latency_ms": 85.0}
    args = SimpleNamespace(out=tmp_path, goal_p99=150.0)
    assert bench.plot_runs(args, recs) == tmp_path / "latency.png" and (tmp_path / "latency.png").stat().st_size > 0
