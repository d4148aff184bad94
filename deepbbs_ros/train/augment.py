"""The augmentation that widens the training pairs' basin (no ROS): the source cloud moved by a random rigid motion A
(yaw up to ``yaw_aug_deg`` about the sensor z axis, translation up to ``trans_aug`` metres), so the ground truth
becomes ``T_target_source @ inv(A)``; one cloud cropped to a partial view (a missing azimuth sector, like an occluding
truck); both clouds sampled independently (a random subset, then farthest-point sampling from a random start) to
``num_points``; Gaussian noise added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.errors import DatasetError
from deepbbs_ros.train.rigid import inv_T, random_motion, transform


@dataclass
class AugmentConfig:
    """What the training pairs vary (filled from ``TrainConfig``)."""

    num_points: int = 1000
    max_dist: float = 5.0  # m; frames at most this far apart make a pair
    yaw_aug_deg: float = 45.0
    trans_aug: float = 1.0  # m
    crop_prob: float = 0.3
    noise_sigma: float = 0.01  # m
    subset_min: float = 0.7  # each cloud is FPS-sampled from a random subset of this fraction or more
    pair_balance: str = "pairs"  # "pairs" or "distance" (train.pair_balance)

    @classmethod
    def from_train(cls, train, num_points: int) -> AugmentConfig:
        return cls(num_points=num_points, max_dist=train.max_dist, yaw_aug_deg=train.yaw_aug_deg,
                   trans_aug=train.trans_aug, crop_prob=train.crop_prob, noise_sigma=train.noise_sigma,
                   pair_balance=train.pair_balance)


def sample_points(points: np.ndarray, n: int, rng: np.random.Generator, subset_min: float = 0.7) -> np.ndarray:
    """(n, 3) float32: farthest-point sampling from a random subset (random start), so two calls on
    the same cloud give different samplings. Clouds with fewer than n points are padded by repeats."""
    import fpsample

    m = len(points)
    if m == 0:
        raise DatasetError("training pairs: a frame has no points after preprocessing")
    if m <= n:
        idx = np.concatenate([rng.permutation(m), rng.integers(0, m, size=n - m)])
        return np.ascontiguousarray(points[idx], dtype=np.float32)
    keep = max(n, int(m * rng.uniform(subset_min, 1.0)))
    sub = points[np.sort(rng.choice(m, size=keep, replace=False))] if keep < m else points
    if keep == n:
        return np.ascontiguousarray(sub, dtype=np.float32)
    start = int(rng.integers(0, keep))
    h = int(np.clip(int(np.log2(keep)) - 7, 3, 9))  # tree height as in core.preprocess
    idx = fpsample.bucket_fps_kdline_sampling(np.ascontiguousarray(sub, dtype=np.float32), n, h, start_idx=start)
    return np.ascontiguousarray(sub[np.asarray(idx, dtype=np.int64)], dtype=np.float32)


def crop_sector(points: np.ndarray, rng: np.random.Generator, min_deg: float = 20.0, max_deg: float = 90.0,
                ) -> np.ndarray:
    """Remove the points of one random azimuth sector (a partial view, e.g. an occluding vehicle)."""
    width = np.deg2rad(rng.uniform(min_deg, max_deg))
    start = rng.uniform(-np.pi, np.pi)
    az = np.arctan2(points[:, 1], points[:, 0])
    inside = np.mod(az - start, 2 * np.pi) < width
    kept = points[~inside]
    return kept if len(kept) >= 0.5 * len(points) else points


def augment_pair(src: np.ndarray, tgt: np.ndarray, T_ts: np.ndarray, rng: np.random.Generator, aug: AugmentConfig,
                 trans_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``src`` / ``tgt`` (N, 3) float32 and their ``T_ts`` (4, 4) ``T_target_source`` augmented: one cloud cropped
    (``crop_prob``), both sampled to ``num_points``, the source moved by a random motion A (translation up to
    ``trans_max`` m; the truth becomes ``T_ts @ inv(A)``), noise added. -> (src, tgt, T_target_source)."""
    if aug.crop_prob > 0 and rng.random() < aug.crop_prob:
        if rng.random() < 0.5:
            src = crop_sector(src, rng)
        else:
            tgt = crop_sector(tgt, rng)
    src = sample_points(src, aug.num_points, rng, aug.subset_min)
    tgt = sample_points(tgt, aug.num_points, rng, aug.subset_min)
    A = random_motion(rng, aug.yaw_aug_deg, trans_max)
    src = transform(src, A)
    T_ts = T_ts @ inv_T(A)
    if aug.noise_sigma > 0:
        src = src + rng.normal(0.0, aug.noise_sigma, src.shape).astype(np.float32)
        tgt = tgt + rng.normal(0.0, aug.noise_sigma, tgt.shape).astype(np.float32)
    return src.astype(np.float32), tgt.astype(np.float32), T_ts
