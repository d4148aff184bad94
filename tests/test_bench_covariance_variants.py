"""The localization covariance's models tried (scripts/benchmarks/_localization_variants.py): the jackknife path is
core/covariance.py's, and CR2's cell weights are ``H^-1 (I - H_c H^-1)^-1/2`` (the push-through identity)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.linalg import sqrtm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
import _localization_variants as variants  # noqa: E402

import deepbbs_ros.core.covariance as cm  # noqa: E402


def _cells(rng, G: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """G random cells' Hessians (each of 40 rank-one terms) and gradients, and their sum H."""
    J = rng.normal(size=(G, 40, 6)) * rng.uniform(0.2, 2.0, size=(G, 1, 6))
    Hc = np.einsum("gni,gnj->gij", J, J)
    return Hc.sum(0), np.einsum("gni,gn->gi", J, rng.normal(size=(G, 40))), Hc


def test_cr2_weights_are_the_inverse_square_root_of_one_less_leverage():
    H, _, Hc = _cells(np.random.default_rng(3))
    A = variants._weights(H, Hc, "cr2")
    Hi = np.linalg.inv(H)
    for c in (0, 7, 29):
        ref = Hi @ np.real(np.linalg.inv(sqrtm(np.eye(6) - Hc[c] @ Hi)))
        np.testing.assert_allclose(A[c], ref, rtol=1e-8, atol=1e-12)


def test_jackknife_path_is_the_shipped_covariance(monkeypatch):
    H, Gc, Hc = _cells(np.random.default_rng(4))
    monkeypatch.setattr(variants, "_terms", lambda pairs, cell: (H, Gc, Hc))
    for student in (False, True):
        cov = variants._one(None, 12.0, "jackknife", student)[0]
        ref = cm.jackknife_meat(H, Gc, Hc)
        ref = cm.student_widened(ref, H, Hc) if student else ref
        np.testing.assert_allclose(cov, ref, rtol=1e-8, atol=1e-14)


def test_matrix_max_holds_both():
    rng = np.random.default_rng(5)
    X, Y = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    A, B = X @ X.T + np.eye(6), Y @ Y.T + np.eye(6)
    M = variants._matrix_max(A, B)
    assert np.linalg.eigvalsh(M - A).min() > -1e-9 and np.linalg.eigvalsh(M - B).min() > -1e-9
    np.testing.assert_allclose(variants._matrix_max(A, A), A, rtol=1e-9)


def test_map_planes_drop_the_scans_own_covariances_from_the_pairs(monkeypatch):
    """``--map-planes`` (a model tried): the localization's covariance pairs weigh the map's planes alone (``C_a = 0``)
    and its refinement runs point-to-plane."""
    import deepbbs_ros.core.localization as locmod
    from deepbbs_ros.core.polish import prepare_polish_cloud

    monkeypatch.setattr(cm, "matched_pairs", cm.matched_pairs)  # restored after the test
    refine = locmod.MapLocalizer._refine
    monkeypatch.setattr(locmod.MapLocalizer, "_refine", refine)
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-10, 10, (4000, 2)), rng.normal(0, 0.02, 4000)]  # a floor
    pts[:1000, 2] = rng.uniform(0, 3, 1000)
    pts[:1000, 0] = 5.0  # a wall
    src, tgt = prepare_polish_cloud(pts, 0.5, 20), prepare_polish_cloud(pts, 0.5, 20)
    own = cm.matched_pairs(src, tgt, np.eye(4), 0.5)
    variants.install_map_planes()
    a, Ca, b, Cb, _ = cm.matched_pairs(src, tgt, np.eye(4), 0.5)
    assert np.abs(own[1]).max() > 0.5 and not Ca.any()
    np.testing.assert_array_equal(Cb, own[3])
    assert locmod.MapLocalizer._refine is not refine  # the point-to-plane refinement
