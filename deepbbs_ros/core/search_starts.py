"""The global search's starts (no ROS): the other start yaws, the shifted starts, the ranking of their answers, the
ranking passes' share of the points, the speculative starts a network process runs ahead, and the batch sizes torch
is warmed up for. What core/global_search.py runs them with, and what the network process needs of it without the
registration.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from deepbbs_ros.core.network import worker_share

SHIFT_STARTS = 17  # _shift_retry: the best pose turned by 180 degrees, and 8 shifted starts around each


def yaw_starts(T_start: np.ndarray, n: int) -> list[np.ndarray]:
    """The ``n - 1`` other starts: ``T_start @ Rz(k * 360 / n)``, k = 1 .. n - 1 ((4, 4) float64 each)."""
    out = []
    for k in range(1, n):
        a = 2.0 * np.pi * k / n
        Rz = np.eye(4)
        Rz[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
        out.append(np.asarray(T_start, dtype=np.float64) @ Rz)
    return out


def shift_starts(T: np.ndarray, shift: float) -> list[np.ndarray]:
    """Eight starts ``shift`` and ``2 * shift`` m from the pose T (4, 4) along +x, -x, +y, -y of the target frame
    (a pose of the right yaw slid along a road by more than the deep passes' reach)."""
    out = []
    for r in (shift, 2.0 * shift):
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            S = np.asarray(T, dtype=np.float64).copy()
            S[:2, 3] += (r * dx, r * dy)
            out.append(S)
    return out


def rank_outputs(outputs: list[tuple[Any, np.ndarray]], score: Callable[[np.ndarray], float]
                 ) -> list[tuple[float, Any, np.ndarray]]:
    """[(output, T_estimate)] ranked by ``score(T_estimate)``: -> [(score, output, T_estimate)] best first (a stable
    sort: ties keep the order of the starts)."""
    ranked = [(float(score(T)), out, T) for out, T in outputs]
    ranked.sort(key=lambda r: -r[0])
    return ranked


def rank_size(rc: Any, n: int) -> int:
    """How many of a cloud's ``n`` sampled points the search's ranking passes use (``registration.global_rank_points``;
    0 or more than ``n``: all): the clouds' first ones, a farthest-point prefix."""
    k = int(rc.global_rank_points)
    return n if k <= 0 or k >= n else k


def full_gamma(out: Any, n: int) -> Any:
    """A ranking pass's output with its gamma (k,) padded with zeros to the ``n`` sampled points (the points it did
    not see carry no weight); other outputs as they are."""
    g = np.asarray(out.gamma)
    if len(g) >= n:
        return out
    return dataclasses.replace(out, gamma=np.concatenate([g, np.zeros(n - len(g), dtype=g.dtype)]))


SPECULATE_WINDOW = 8  # registration.global_speculate "auto": speculate when the search ran in one of the last 8


def speculative_starts(rc: Any, T_start: np.ndarray, searched: Any = ()) -> np.ndarray | None:
    """The other start yaws (K-1, 4, 4) the network process runs after the given start's passes, while the caller
    still builds the GICP clouds (``registration.global_speculate``; "auto": ``searched``, whether the search ran in
    each of the last registrations, is empty or holds a True), or None."""
    if rc.global_search == "off" or rc.global_yaws < 2 or rc.global_speculate == "off" or not rc.deep:
        return None
    if rc.global_speculate == "auto" and len(searched) and not any(searched):
        return None
    return np.stack(yaw_starts(T_start, rc.global_yaws))


def batch_sizes(rc: Any) -> tuple[list[int], list[int], list[int]]:
    """The batch sizes of the search's deep passes (``registration.global_*``) for warming torch up: (in the network
    process, in the caller while the network process runs its share, in the caller alone)."""
    if rc.global_search == "off" or rc.global_yaws < 2:
        return [], [], []
    counts = [rc.global_yaws - 1] + ([SHIFT_STARTS] if rc.global_shift > 0 else [])
    return ([worker_share(n) for n in counts], [n - worker_share(n) for n in counts], counts)
