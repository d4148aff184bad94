"""Training and validation pairs with their ground truth, augmented to widen the basin.

A pair is (source, target, T_target_source): p_target = R p_source + t (CONVENTIONS.md). From two
frames i (source) and j (target) of a drive with ground truth,
``T_target_source = inv(T_world_lidar[j]) @ T_world_lidar[i]``, then augmented
(:mod:`deepbbs_ros.train.augment`: a random motion of the source, a crop, sampling, noise; the rigid-motion helpers
are :mod:`deepbbs_ros.train.rigid`'s).

Recordings without ground truth give self-supervised pairs: two different samplings and crops of the
same scan, the source moved by a known random motion (translation up to ``max_dist``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepbbs_ros.errors import DatasetError
from deepbbs_ros.train.augment import AugmentConfig, augment_pair, crop_sector, sample_points  # noqa: F401  (re-exported)
from deepbbs_ros.train.cache import Drive
from deepbbs_ros.train.rigid import inv_T, make_T, random_motion, transform, yaw_matrix  # noqa: F401  (re-exported)


@dataclass
class Pair:
    """One registration problem with its answer.

    Attributes:
        source: (N, 3) float32, source sensor frame, metres.
        target: (M, 3) float32, target sensor frame, metres.
        T_target_source: (4, 4) float64 ground truth.
        scene: scene type (``urban``, ..., ``recording``) for per-scene reports.
        ref: ``drive:i->j`` for traceability.
    """

    source: np.ndarray
    target: np.ndarray
    T_target_source: np.ndarray
    scene: str = ""
    ref: str = ""


# -- pair index ----------------------------------------------------------------------------------
def frame_pairs(drive: Drive, max_dist: float, min_points: int = 50) -> np.ndarray:
    """(K, 2) int64 (source i, target j) with i != j and GT positions at most ``max_dist`` apart.

    Drives without ground truth give (i, i): self-supervised pairs.
    """
    counts = np.diff(drive.offsets)
    ok = np.flatnonzero(counts >= min_points)
    if not drive.has_gt:
        return np.stack([ok, ok], axis=1).astype(np.int64)
    pos = drive.T_world_lidar[ok, :3, 3]
    d = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=-1)
    ii, jj = np.nonzero((d <= max_dist) & ~np.eye(len(ok), dtype=bool))
    return np.stack([ok[ii], ok[jj]], axis=1).astype(np.int64)


class PairSampler:
    """Draws augmented training pairs from cached drives.

    Every draw depends only on the generator passed in, so a saved generator state reproduces the
    same pairs after a resume.
    """

    def __init__(self, drives: list[Drive], aug: AugmentConfig):
        self.drives = drives
        self.aug = aug
        self.pairs = [frame_pairs(d, aug.max_dist) for d in drives]
        self._valid = [k for k, p in enumerate(self.pairs) if len(p)]
        if not self._valid:
            raise DatasetError(
                f"training pairs: no frame pair within max_dist={aug.max_dist} m in {len(drives)} drive(s)"
            )
        self._bins: list[list[np.ndarray]] | None = None
        if aug.pair_balance == "distance":  # every drive alike; within one, the distance uniform over its bins
            self._p = np.full(len(self._valid), 1.0 / len(self._valid))
            self._bins = [_distance_bins(drives[k], self.pairs[k], aug.max_dist) for k in self._valid]
        else:  # drives in proportion to their pair count, capped so no drive dominates
            w = np.array([min(len(self.pairs[k]), 2000) for k in self._valid], dtype=np.float64)
            self._p = w / w.sum()

    @property
    def num_pairs(self) -> int:
        return int(sum(len(p) for p in self.pairs))

    def draw(self, rng: np.random.Generator) -> Pair:
        v = int(rng.choice(len(self._valid), p=self._p))
        k = self._valid[v]
        drive = self.drives[k]
        if self._bins is not None:
            group = self._bins[v][int(rng.integers(len(self._bins[v])))]
            i, j = (int(x) for x in self.pairs[k][int(group[rng.integers(len(group))])])
        else:
            i, j = (int(x) for x in self.pairs[k][int(rng.integers(len(self.pairs[k])))])
        return make_pair(drive, i, j, rng, self.aug)

    def batch(self, rng: np.random.Generator, batch_size: int) -> list[Pair]:
        return [self.draw(rng) for _ in range(batch_size)]


def _distance_bins(drive: Drive, pairs: np.ndarray, max_dist: float) -> list[np.ndarray]:
    """The indices into ``pairs`` grouped by the pair's distance in tenths of ``max_dist`` (non-empty groups)."""
    if not drive.has_gt:
        return [np.arange(len(pairs))]
    pos = drive.T_world_lidar[:, :3, 3]
    dist = np.linalg.norm(pos[pairs[:, 0]] - pos[pairs[:, 1]], axis=1)
    b = np.minimum((dist / (max_dist / 10)).astype(np.int64), 9)
    return [np.flatnonzero(b == v) for v in np.unique(b)]


def make_pair(drive: Drive, i: int, j: int, rng: np.random.Generator, aug: AugmentConfig) -> Pair:
    """Source = frame i, target = frame j of ``drive``, augmented; ground truth included."""
    if drive.has_gt and i != j:
        T_ts = inv_T(drive.T_world_lidar[j]) @ drive.T_world_lidar[i]
        trans_max = aug.trans_aug
    else:
        # self-supervised: the same scan twice, a known motion as large as a real one
        T_ts = np.eye(4)
        trans_max = max(aug.trans_aug, aug.max_dist)
    src, tgt, T = augment_pair(drive.frame(i), drive.frame(j), T_ts, rng, aug, trans_max)
    return Pair(src, tgt, T, scene=drive.scene, ref=f"{drive.name}:{i}->{j}")


def collate(pairs: list[Pair]):
    """Stack pairs into float32 torch tensors: src (B, N, 3), tgt (B, M, 3), R_gt (B, 3, 3), t_gt (B, 3)."""
    import torch

    src = torch.from_numpy(np.stack([p.source for p in pairs]).astype(np.float32))
    tgt = torch.from_numpy(np.stack([p.target for p in pairs]).astype(np.float32))
    T = np.stack([p.T_target_source for p in pairs])
    R = torch.from_numpy(T[:, :3, :3].astype(np.float32))
    t = torch.from_numpy(T[:, :3, 3].astype(np.float32))
    return src, tgt, R, t


# -- validation pairs (fixed) ----------------------------------------------------------------------
def protocol_pairs(drive: Drive, stride: int, max_dist: float) -> list[tuple[int, int]]:
    """CONVENTIONS.md pair protocol: sources every ``stride`` frames, target = the last j > i whose
    GT position is within ``max_dist`` of frame i's."""
    if not drive.has_gt:
        return []
    pos = drive.T_world_lidar[:, :3, 3]
    out = []
    for i in range(0, len(drive) - 1, stride):
        d = np.linalg.norm(pos[i + 1 :] - pos[i], axis=1)
        within = np.flatnonzero(d <= max_dist)
        if len(within):
            out.append((i, i + 1 + int(within[-1])))
    return out


def validation_pairs(drives: list[Drive], num_points: int, *, stride: int = 10, max_dist: float = 5.0,
                     yaw_deg: float = 0.0, seed: int = 0, per_drive: int = 0) -> list[Pair]:
    """A fixed set of held-out pairs (protocol pairs, deterministic FPS sampling to ``num_points``),
    optionally with an extra random yaw of up to ``yaw_deg`` applied to every source."""
    from deepbbs_ros.core.preprocess import farthest_point_sample

    rng = np.random.default_rng([seed, 4242])
    out: list[Pair] = []
    for drive in drives:
        idx = protocol_pairs(drive, stride, max_dist)
        if per_drive:
            idx = idx[:per_drive]
        for i, j in idx:
            clouds = []
            for f in (i, j):
                # exactly num_points, as the registration's preprocessing gives (FPS order repeated
                # cyclically when a frame has fewer points)
                pts = drive.frame(f)
                pts = pts[farthest_point_sample(pts, num_points, seed=seed + f)]
                clouds.append(np.ascontiguousarray(pts, dtype=np.float32))
            T = inv_T(drive.T_world_lidar[j]) @ drive.T_world_lidar[i]
            src = clouds[0]
            if yaw_deg > 0:
                A = make_T(yaw_matrix(np.deg2rad(rng.uniform(-yaw_deg, yaw_deg))), np.zeros(3))
                src = transform(src, A)
                T = T @ inv_T(A)
            out.append(Pair(src, clouds[1], T, scene=drive.scene, ref=f"{drive.name}:{i}->{j}"))
    return out
