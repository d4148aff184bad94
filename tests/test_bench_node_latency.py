"""scripts/bench_node_latency.py's streams: real KITTI-style scans in the driver layouts the node decodes (the
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
    spec = importlib.util.spec_from_file_location("bench_node_latency", ROOT / "scripts" / "bench_node_latency.py")
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
