"""The innovations line of scripts/benchmarks/covariance.py (scripts/benchmarks/_innovations.py), with known geometry:
steps whose rotation errors are independent with their published GICP variance and a constant true motion (the
premises of ``--sweep-floor adaptive``) show the innovations and the steps' errors alike; steps sharing one error show
none of it in the innovations."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import _innovations  # noqa: E402

G = 1e-6  # rad^2: a step's GICP variance per rotation axis


def _rows(errors: np.ndarray):
    """(steps, chain, floors) of a drive turning by a constant true motion, each step off by ``errors[k]`` (3,) rad in
    rotation, covariance ``G`` per axis, no floor."""
    from scipy.spatial.transform import Rotation

    M = np.eye(4)
    M[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 0.02]).as_matrix()
    M[0, 3] = 1.0
    steps, chain, floors, T = [], [], [], np.eye(4)
    for e in errors:
        E = np.eye(4)
        E[:3, :3] = Rotation.from_rotvec(e).as_matrix()
        D = M @ E
        steps.append((np.concatenate([np.zeros(3), e]), G * np.eye(6)))
        chain.append((T, D, T @ D, None))
        floors.append(np.zeros((6, 6)))
        T = T @ D
    return steps, chain, floors


def _ratios(line: str) -> tuple[np.ndarray, np.ndarray]:
    inn, err = line.split("(roll, pitch, yaw) ")[1].split("; the steps' errors over theirs ")
    return (np.array([float(x) for x in inn.split(", ")]),
            np.array([float(x) for x in err.split(" (")[0].split(", ")]))


def test_independent_errors_show_alike():
    errors = np.random.default_rng(0).normal(0.0, G ** 0.5, (2000, 3))
    inn, err = _ratios(_innovations.innovation_line(*_rows(errors)))
    assert np.allclose(err, 1.0, atol=0.1)  # chi-square(1)'s mean over ~2000 steps
    assert np.allclose(inn, err, atol=0.15)  # the premises: equal


def test_a_shared_error_does_not_show():
    errors = np.tile([1e-3, -2e-3, 5e-4], (50, 1))  # every step off by the same rotation
    inn, err = _ratios(_innovations.innovation_line(*_rows(errors)))
    assert np.allclose(err, [1.0, 4.0, 0.25], rtol=1e-6) and np.all(inn < 1e-6)
