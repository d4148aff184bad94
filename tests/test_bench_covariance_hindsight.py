"""The covariance benchmark's hindsight check (scripts/benchmarks/covariance.py ``hindsight_rows``): the steps'
rotation floor replaced by the set's own root mean square rotation error, the rest of each covariance kept."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import covariance as bench  # noqa: E402

from deepbbs_ros.core.motion_floor import floor_term  # noqa: E402


def _pose(rng) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, 5, 3)
    return T


def test_hindsight_replaces_the_rotation_floor_and_keeps_the_rest():
    rng = np.random.default_rng(2)
    steps, chain, floors, parts = [], [], [], []
    for _ in range(5):
        T_prev, T = _pose(rng), _pose(rng)
        floor = np.array([0.01, 0.02, 0.03, 1e-3, 2e-3, 3e-3])
        A = rng.normal(size=(6, 6)) * 1e-3
        part = A @ A.T  # the GICP part, scan k-1's frame
        fl = floor_term(floor, T)  # odometry frame
        steps.append((rng.normal(0, 1e-3, 6), part + bench._in_prev(T_prev, fl)))
        chain.append((T_prev, None, T, None))
        floors.append(fl)
        parts.append((part, T_prev, T, floor))
    rot = np.sqrt(np.mean(np.square([d[3:] for d, _ in steps]), axis=0))
    for (_, S), (part, T_prev, T, floor) in zip(bench.hindsight_rows(steps, chain, floors), parts):
        want = part + bench._in_prev(T_prev, floor_term(np.concatenate([floor[:3], rot]), T))
        assert np.allclose(S, want)
