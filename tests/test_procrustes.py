"""Weighted Procrustes against seeded random exact transforms (after pytorch3d's alignment tests)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from deepbbs_ros.core.procrustes import apply_transform, compose, weighted_procrustes


def _random_transforms(rng: np.random.Generator, b: int) -> tuple[torch.Tensor, torch.Tensor]:
    R = Rotation.random(b, random_state=int(rng.integers(1 << 31))).as_matrix()
    t = rng.normal(scale=5.0, size=(b, 3))
    return torch.tensor(R, dtype=torch.float64), torch.tensor(t, dtype=torch.float64)


@pytest.mark.parametrize("n", [3, 10, 500])
def test_recovers_exact_transform(rng, n):
    b = 8
    R_gt, t_gt = _random_transforms(rng, b)
    src = torch.tensor(rng.normal(scale=3.0, size=(b, n, 3)))
    tgt = apply_transform(src, R_gt, t_gt)
    R, t = weighted_procrustes(src, tgt)
    torch.testing.assert_close(R, R_gt, atol=1e-8, rtol=0)
    torch.testing.assert_close(t, t_gt, atol=1e-8, rtol=0)
    assert torch.allclose(torch.det(R), torch.ones(b, dtype=R.dtype))


def test_zero_weights_ignore_outliers(rng):
    b, n = 4, 100
    R_gt, t_gt = _random_transforms(rng, b)
    src = torch.tensor(rng.normal(size=(b, n, 3)), dtype=torch.float32)
    tgt = apply_transform(src.double(), R_gt, t_gt).float()
    outliers = torch.tensor(rng.random((b, n)) < 0.3)
    tgt[outliers] += torch.tensor(rng.normal(scale=20.0, size=(int(outliers.sum()), 3)), dtype=torch.float32)
    w = (~outliers).float() * torch.tensor(rng.uniform(0.5, 2.0, size=(b, n)), dtype=torch.float32)
    R, t = weighted_procrustes(src, tgt, w)
    torch.testing.assert_close(R.double(), R_gt, atol=1e-4, rtol=0)
    torch.testing.assert_close(t.double(), t_gt, atol=1e-4, rtol=0)
    # without the weights the outliers pull the estimate away
    R_u, _ = weighted_procrustes(src, tgt)
    assert (R_u.double() - R_gt).abs().max() > 1e-2


def test_reflection_in_data_gives_proper_rotation(rng):
    """Target = mirrored source: the SVD solution would be a reflection; det R must stay +1."""
    src = torch.tensor(rng.normal(size=(2, 50, 3)))
    tgt = src * torch.tensor([1.0, 1.0, -1.0])
    R, _ = weighted_procrustes(src, tgt)
    torch.testing.assert_close(torch.det(R), torch.ones(2, dtype=R.dtype))
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3, dtype=R.dtype).expand(2, 3, 3))


def test_planar_points_recover_rotation(rng):
    """Coplanar points (rank-2 covariance): the reflection fix makes the answer unique."""
    R_gt, t_gt = _random_transforms(rng, 3)
    src = torch.tensor(rng.normal(size=(3, 40, 3)))
    src[..., 2] = 0.0
    R, t = weighted_procrustes(src, apply_transform(src, R_gt, t_gt))
    torch.testing.assert_close(R, R_gt, atol=1e-8, rtol=0)


def test_all_zero_weights_fall_back_to_uniform(rng):
    R_gt, t_gt = _random_transforms(rng, 1)
    src = torch.tensor(rng.normal(size=(1, 20, 3)))
    R, t = weighted_procrustes(src, apply_transform(src, R_gt, t_gt), torch.zeros(1, 20, dtype=torch.float64))
    assert torch.isfinite(R).all() and torch.isfinite(t).all()
    torch.testing.assert_close(R, R_gt, atol=1e-8, rtol=0)


def test_degenerate_covariance_warns():
    src = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])  # collinear
    with pytest.warns(RuntimeWarning, match="rank < 2"):
        R, t = weighted_procrustes(src, src + 1.0)
    assert torch.isfinite(R).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        weighted_procrustes(src, src, warn_degenerate=False)


def test_unbatched_equals_batched_and_shape_errors(rng):
    R_gt, t_gt = _random_transforms(rng, 2)
    src = torch.tensor(rng.normal(size=(2, 30, 3)))
    tgt = apply_transform(src, R_gt, t_gt)
    R, t = weighted_procrustes(src, tgt)
    R0, t0 = weighted_procrustes(src[0], tgt[0])
    torch.testing.assert_close(R0, R[0])
    torch.testing.assert_close(t0, t[0])
    with pytest.raises(ValueError, match="must both be"):
        weighted_procrustes(src, tgt[:, :10])
    with pytest.raises(ValueError, match="weights must be"):
        weighted_procrustes(src, tgt, torch.ones(2, 5, dtype=src.dtype))


def test_compose_matches_sequential_application(rng):
    R1, t1 = _random_transforms(rng, 2)
    R2, t2 = _random_transforms(rng, 2)
    p = torch.tensor(rng.normal(size=(2, 7, 3)))
    R, t = compose(R2, t2, R1, t1)
    torch.testing.assert_close(apply_transform(p, R, t), apply_transform(apply_transform(p, R1, t1), R2, t2))


def test_gradient_is_finite(rng):
    R_gt, t_gt = _random_transforms(rng, 2)
    src = torch.tensor(rng.normal(size=(2, 30, 3)))
    tgt = apply_transform(src, R_gt, t_gt) + 0.01 * torch.tensor(rng.normal(size=(2, 30, 3)))
    w = torch.rand(2, 30, dtype=torch.float64, requires_grad=True)
    tgt.requires_grad_(True)
    R, t = weighted_procrustes(src, tgt, w)
    (R.sum() + t.sum()).backward()
    assert torch.isfinite(w.grad).all() and w.grad.abs().sum() > 0
    assert torch.isfinite(tgt.grad).all()
