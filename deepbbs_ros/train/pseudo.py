"""Pseudo-labels from a recording without ground truth: the pipeline's own accepted answers, cross-checked.

A user's recording is split by time (:func:`split_frames`): the first part adapts the network, the last part is
held back for the before / after report, with a gap of frames between them so that no held-back scan is a
neighbour of an adaptation scan. On the adaptation part, pairs of nearby scans (source i, target i + s for every
stride s, :func:`candidate_pairs`) are registered by the shipped pipeline; a pair is a label when its verdict
(``RegistrationResult.valid``) accepts it and the triplets it belongs to agree (:func:`cycle_consistency`):

    T_c_a ~ T_c_b @ T_b_a   for frames a < b < c with all three pairs accepted,

within ``rot_tol_deg`` / ``trans_tol``. A wrong answer rarely closes a cycle with two right ones, so a pair is kept
when more of its triplets agree than disagree (at least one). Poses of the recording, when it has any, never
enter here: they only grade the labels afterwards (:func:`label_quality`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from deepbbs_ros.errors import DatasetError


@dataclass
class Labels:
    """Registered pairs of one recording. ``T[k]`` is the pipeline's ``T_target_source`` of source frame ``i[k]``
    onto target frame ``j[k]`` (frame numbers in the recording, (K,) int64; T (K, 4, 4) float64); ``score`` (K,) the
    verdict's score, ``valid`` (K,) its acceptance, ``kept`` (K,) accepted and consistent: the training labels."""

    i: np.ndarray
    j: np.ndarray
    T: np.ndarray
    score: np.ndarray
    valid: np.ndarray
    kept: np.ndarray

    def save(self, path: str | Path) -> None:
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "wb") as fh:
            np.savez(fh, i=self.i, j=self.j, T=self.T, score=self.score, valid=self.valid, kept=self.kept)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> Labels:
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls(*(z[k] for k in ("i", "j", "T", "score", "valid", "kept")))
        except (OSError, KeyError, ValueError) as err:
            raise DatasetError(f"adapt: {path} is not a pseudo-label file ({err})") from err

    def __len__(self) -> int:
        return int(len(self.i))


def split_frames(n: int, held_frac: float = 0.3, gap: int = 5) -> tuple[list[int], list[int]]:
    """(adaptation frames, held-back frames) of an ``n``-frame recording: the last ``held_frac`` held back, ``gap``
    frames between the two dropped."""
    if not 0.0 < held_frac < 1.0:
        raise DatasetError(f"adapt: the held-back share must be in (0, 1), got {held_frac}")
    held = max(2, int(np.ceil(n * held_frac)))
    last_adapt = n - held - max(0, gap)
    if last_adapt < 3:
        raise DatasetError(f"adapt: {n} scans are too few to split into an adaptation part, a gap of {gap} and "
                           f"{held} held-back scans")
    return list(range(last_adapt)), list(range(n - held, n))


def candidate_pairs(frames: Sequence[int], strides: Sequence[int]) -> list[tuple[int, int]]:
    """(source i, target i + s) for every frame i and stride s with both frames in ``frames``."""
    have = set(frames)
    return [(i, i + s) for s in sorted(set(strides)) for i in frames if i + s in have]


def register_pairs(register: Callable[[int, int], tuple[np.ndarray, float, bool]], pairs: Sequence[tuple[int, int]],
                   progress: Callable[[int], None] | None = None) -> Labels:
    """``register(i, j)`` -> (T_target_source, score, valid) for every pair; ``kept`` = ``valid`` until
    :func:`cycle_consistency` narrows it."""
    Ts, scores, valid = [], [], []
    for i, j in pairs:
        T, s, ok = register(i, j)
        Ts.append(np.asarray(T, dtype=np.float64))
        scores.append(float(s))
        valid.append(bool(ok) and bool(np.all(np.isfinite(T))))
        if progress:
            progress(1)
    ij = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    v = np.asarray(valid, dtype=bool)
    return Labels(ij[:, 0], ij[:, 1], np.asarray(Ts, dtype=np.float64).reshape(-1, 4, 4),
                  np.asarray(scores, dtype=np.float64), v, v.copy())


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation degrees, translation metres) between two (4, 4) transforms."""
    R = T_a[:3, :3].T @ T_b[:3, :3]
    rot = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))
    return rot, float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))


def cycle_consistency(labels: Labels, rot_tol_deg: float = 1.0, trans_tol: float = 0.3) -> dict[str, int]:
    """Narrow ``labels.kept`` to the accepted pairs more of whose triplets agree than disagree (at least one).
    Returns counts: triplets checked and agreeing, pairs accepted and kept."""
    acc = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(labels.i, labels.j, strict=True)) if labels.valid[k]}
    ok = np.zeros(len(labels), dtype=np.int64)
    bad = np.zeros(len(labels), dtype=np.int64)
    outgoing: dict[int, list[int]] = {}
    for a, b in acc:
        outgoing.setdefault(a, []).append(b)
    triplets = agree = 0
    for (a, c), k_ac in acc.items():
        for b in outgoing.get(a, []):
            if not a < b < c or (b, c) not in acc:
                continue
            k_ab, k_bc = acc[(a, b)], acc[(b, c)]
            rot, tr = pose_error(labels.T[k_ac], labels.T[k_bc] @ labels.T[k_ab])
            good = rot <= rot_tol_deg and tr <= trans_tol
            triplets += 1
            agree += int(good)
            for k in (k_ac, k_ab, k_bc):
                (ok if good else bad)[k] += 1
    labels.kept = labels.valid & (ok >= 1) & (ok > bad)
    return {"triplets": triplets, "triplets_agreeing": agree, "accepted": int(labels.valid.sum()),
            "kept": int(labels.kept.sum())}


def label_quality(labels: Labels, T_world_lidar: np.ndarray, rot_deg: float = 1.0, trans: float = 0.3,
                  ) -> dict[str, int]:
    """Grades the labels against the recording's poses (the report only; never fed back): how many accepted and
    kept pairs are wrong (beyond ``rot_deg`` / ``trans``), and how many right answers the verdict rejected."""
    wrong = np.zeros(len(labels), dtype=bool)
    for k in range(len(labels)):
        T_gt = np.linalg.inv(T_world_lidar[labels.j[k]]) @ T_world_lidar[labels.i[k]]
        r, t = pose_error(labels.T[k], T_gt)
        wrong[k] = not (r <= rot_deg and t <= trans)
    return {"pairs": len(labels), "accepted": int(labels.valid.sum()),
            "accepted_wrong": int((labels.valid & wrong).sum()), "kept": int(labels.kept.sum()),
            "kept_wrong": int((labels.kept & wrong).sum()), "rejected_right": int((~labels.valid & ~wrong).sum())}
