"""A view of a larger prepared cloud (:class:`PolishView`): a map crop as the precision stage's target, with no
preparation of its own (the map's voxel grid, k-d tree and covariances, built once, seen from the crop's frame).
No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.core.polish_cloud import PolishCloud

__all__ = ["PolishView"]


class _FramedTree:
    """A prepared cloud's k-d tree (frame B) queried with points in frame A: they are moved by ``T_b_a`` first."""

    def __init__(self, base: Any, T_b_a: np.ndarray) -> None:
        self.base = base
        self.R, self.t = np.asarray(T_b_a, np.float64)[:3, :3].copy(), np.asarray(T_b_a, np.float64)[:3, 3].copy()

    def batch_nearest_neighbor_search(self, points: np.ndarray, num_threads: int = 1) -> Any:
        p = np.asarray(points, dtype=np.float64) @ self.R.T + self.t
        return self.base.batch_nearest_neighbor_search(p, num_threads=num_threads)


@dataclass(eq=False)
class PolishView(PolishCloud):
    """A part of a larger prepared cloud (a map's: voxel grid, k-d tree and covariances built once, frame B) seen
    from frame A: the precision-stage target of a map crop with no preparation of its own. ``local`` (n_points, 3)
    float64 the part's voxel centroids in frame A (``points()``), ``T_base`` (4, 4) ``T_b_a``. core.polish.polish aligns
    on the whole base cloud from ``T_base @ T_init`` and answers in frame A (GICP is the same in any frame, to
    rounding); ``tree`` answers queries in frame A. Pickled as a plain deferred :class:`PolishCloud` of ``local``."""

    T_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    local: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @classmethod
    def of(cls, base: PolishCloud, local: np.ndarray, T_b_a: np.ndarray) -> PolishView:
        """The view of ``base`` (completed here) whose centroids in frame A are ``local`` (N, 3), ``T_b_a`` (4, 4)."""
        base.complete()
        T = np.asarray(T_b_a, dtype=np.float64).copy()
        return cls(base.cloud, _FramedTree(base.tree, T), len(local), n_cropped=len(local), spec=base.spec,
                   T_base=T, local=np.ascontiguousarray(local, dtype=np.float64))

    def points(self) -> np.ndarray:
        return self.local.copy()

    def at(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The base cloud's points and unit normals at indices ``idx`` (K,) of its k-d tree's answers, in frame A ->
        ((K, 3), (K, 3)) float64."""
        P, N = base_arrays(self.cloud)
        R, t = self.tree.R, self.tree.t
        return (P[idx] - t) @ R, N[idx].astype(np.float64) @ R

    def __reduce__(self) -> tuple:
        return _plain_cloud, (self.__getstate__(),)


def base_arrays(cloud: Any) -> tuple[np.ndarray, np.ndarray]:
    """(points (M, 3), unit normals (M, 3)) float32 of a map's whole GICP cloud (the base of its crops' views, its
    frame), read once per map (the last map's kept: a node holds one)."""
    global _BASE
    kept = _BASE  # one assignment below: a thread beside this one sees the old pair or the new one
    if kept[0] is not cloud:
        kept = (cloud, (np.asarray(cloud.points())[:, :3].astype(np.float32),
                        np.asarray(cloud.normals())[:, :3].astype(np.float32)))
        _BASE = kept
    return kept[1]


_BASE: tuple[Any, Any] = (None, None)  # (the map's GICP cloud, its points and normals)


def _plain_cloud(state: dict) -> PolishCloud:
    pc = PolishCloud.__new__(PolishCloud)
    pc.__setstate__(state)
    return pc

