"""How much of a bend within the sweep a scan's registered pose takes (scripts/benchmarks/covariance.py's
``--sweep-floor share`` and its ``sweep: share`` line; a model tried, not the node's).

A sweep deskewed with a velocity off by ``e`` (a twist per period: the motion the deskew missed) leaves each point
turned by ``s e`` about the scan's pose at its stamp, ``s = t / period`` its time in the sweep (``t`` seconds since
the stamp): the scan is bent, not moved. GICP then moves the pose by the least-squares answer to those per-point
perturbations, ``H^-1 sum_i s_i J_i^T M_i J_i e``: the pairs' Hessian weighted by each point's time in the sweep
over the plain one (:func:`share_matrix`). A scan whose constraining points were all measured at the stamp takes none
of the bend, one whose points were all measured a period from it all of it, a uniform sweep about half; which points
pin roll, pitch and yaw, and when they were measured, differ per scan (:func:`point_times` carries the per-point
times past the voxel grid).

``share`` floor (:func:`white_floor`): scan ``k``'s pose is off by ``a_k b_k`` (``a_k`` its share per rotation
axis, ``b_k`` its sweep's bend), so a step is off by ``a_k b_k - a_{k-1} b_{k-1}``, and the deviation of the
registered motion from the deskew's shows ``a_k b_k + (1 - a_{k-1}) b_{k-1}``; with bends independent from scan to
scan the step's variance is ``(a_k^2 + a_{k-1}^2)`` times the deviations' mean square over ``(1 - a)^2 + a^2``
(``a`` the window's mean share): 1 where every share is a half, where the node's floor takes 2.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from deepbbs_ros.core.gicp_pairs import cell_terms, voxel_pairs


def _keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """(n, 3) points -> (n,) int64 keys of their ``resolution``-m voxels (21 bits per axis)."""
    c = (np.floor(points / resolution).astype(np.int64) + (1 << 20)) & ((1 << 21) - 1)
    return (c[:, 0] << 42) | (c[:, 1] << 21) | c[:, 2]


def point_times(frame: np.ndarray, times: np.ndarray, resolution: float, query: np.ndarray) -> np.ndarray:
    """(m,) the mean time of the ``frame`` (n, 3) points (``times`` (n,)) in the ``resolution``-m voxel of each
    ``query`` point (m, 3): the time of a voxel-grid centroid (a centroid lies in its own voxel); NaN where the voxel
    holds no frame point."""
    keys = _keys(np.asarray(frame, dtype=np.float64), resolution)
    order = np.argsort(keys, kind="stable")
    sk = keys[order]
    cs = np.concatenate([[0.0], np.cumsum(np.asarray(times, dtype=np.float64)[order])])
    q = _keys(np.asarray(query, dtype=np.float64), resolution)
    lo, hi = np.searchsorted(sk, q, "left"), np.searchsorted(sk, q, "right")
    n = hi - lo
    return np.where(n > 0, (cs[hi] - cs[lo]) / np.maximum(n, 1), np.nan)


def share_matrix(pairs: tuple[np.ndarray, ...], s: np.ndarray) -> np.ndarray | None:
    """(6, 6) ``H^-1 H_s`` in small_gicp's right perturbation ``[rot, trans]`` of the source: the pose's move per unit
    twist ``e`` when every pair's source point is perturbed by ``s_i e`` (``s`` (n,) per pair). ``pairs``: (a, Ca, b,
    Cb, T) as core/gicp_pairs.py gives them. None where ``H`` is singular."""
    a, Ca, b, Cb, T = pairs
    H = cell_terms(a, Ca, b, Cb, T, 1e9)[0]
    Hs = cell_terms(a, Ca, b, Cb, T, 1e9, weights=np.asarray(s, dtype=np.float64))[0]
    try:
        return np.linalg.solve(H, Hs)
    except np.linalg.LinAlgError:
        return None


def sweep_share(pairs: tuple[np.ndarray, ...] | None, frame: np.ndarray | None, times: np.ndarray | None,
                period: float, resolution: float) -> np.ndarray | None:
    """(3,) per rotation axis of the scan (roll, pitch, yaw) the share of the bend its pose takes: the magnitude of
    the diagonal of :func:`share_matrix`'s rotation block. ``frame`` (n, 3): the deskewed scan whose
    ``resolution``-m voxel centroids are the ``pairs``' source points, ``times`` (n,) s since the stamp; None
    without times or pairs."""
    if pairs is None or frame is None or times is None or not period > 0 or len(times) != len(frame):
        return None
    t = point_times(frame, times, resolution, pairs[0])
    ok = np.isfinite(t)
    if ok.sum() < 7:
        return None
    a, Ca, b, Cb, T = pairs
    A = share_matrix((a[ok], Ca[ok], b[ok], Cb[ok], T), t[ok] / period)
    return None if A is None else np.abs(np.diag(A)[:3])


def white_floor(swept: Any, shares: Any) -> np.ndarray:
    """(3,) rad: the ``share`` floor per rotation axis (module docstring) from the deviations ``swept`` (K, 3) and
    the scans' shares ``shares`` (K, 3), oldest first."""
    d, a = np.asarray(swept, dtype=np.float64), np.asarray(shares, dtype=np.float64)
    ak, ap = a[-1], a[-2] if len(a) > 1 else a[-1]
    abar = a.mean(axis=0)
    return np.sqrt((ak ** 2 + ap ** 2) * np.mean(np.square(d), axis=0) / ((1.0 - abar) ** 2 + abar ** 2))


def install(odometry_module: Any, floor_module: Any) -> None:
    """Patch core/odometry.py's ``DeepBBSOdometry`` and core/motion_floor.py's ``MotionFloor`` so that each scan's
    share is measured before the floor is (``odometry.share`` the last one) and the sweep floor is
    :func:`white_floor` (``--sweep-floor share``); without it (:func:`install_share_only`) only measured."""
    install_share_only(odometry_module, floor_module)

    def floor(self: Any) -> np.ndarray:
        return white_floor(self._swept, list(self._shares)[-len(self._swept):])

    floor_module.MotionFloor._sweep_floor = floor


def install_share_only(odometry_module: Any, floor_module: Any) -> None:
    """Measure each scan's share (``DeepBBSOdometry.share``: (3,) or None) at its pose on the map before it joins,
    and keep it beside the floor's deviations (``MotionFloor._shares``)."""
    odo_cls, floor_cls = odometry_module.DeepBBSOdometry, floor_module.MotionFloor
    if getattr(odo_cls, "_share_installed", False):
        return
    prepare, deskew, update, reset = odo_cls._prepare, odo_cls._deskew, floor_cls.update, odo_cls.reset

    def _prepare(self: Any, frame: np.ndarray) -> Any:
        cloud = prepare(self, frame)
        self._share_input = (cloud, frame, self.sweep_times)
        return cloud

    def _deskew(self: Any, *a: Any, **k: Any) -> np.ndarray:
        self.share = None
        return deskew(self, *a, **k)

    def _update(self: Any, pose: np.ndarray, prediction: Any, motion: Any = None, swept: Any = None,
                held: bool = False) -> Any:
        odo = getattr(self, "_odometry", None)
        if odo is not None and prediction is not None and motion is not None and swept is not None:
            cloud, frame, times = odo._share_input
            pairs = voxel_pairs(cloud, odo._map, pose, odo.voxel_size, 2000)
            odo.share = sweep_share(pairs, frame, times, odo.period, 0.5 * odo.voxel_size)
            if not hasattr(self, "_shares"):
                self._shares = deque(maxlen=self._swept.maxlen)
            # a scan without a share (no pairs with times): a uniform sweep's half
            self._shares.append(odo.share if odo.share is not None else np.full(3, 0.5))
        return update(self, pose, prediction, motion, swept, held)

    def _reset(self: Any) -> None:
        reset(self)
        self._sweep._odometry = self

    odo_cls._prepare, odo_cls._deskew, floor_cls.update, odo_cls.reset = _prepare, _deskew, _update, _reset
    odo_cls._share_installed = True
