"""The odometry's hold: where the data pin a direction less than the prediction does, the prediction's position stays
(no ROS import).

A step whose position slid from the constant-velocity prediction beyond the motion model's gate (core/degeneracy.py
``MotionGate``) along an eigen-direction ``d`` of the alignment's translation Hessian is one of two things: the
motion changed (the data say so, precisely) or the alignment slid along a direction the data barely pin (a straight
road, a corridor). The two standard deviations along ``d`` tell them apart:

* the data's: ``sqrt(d^T Sigma d)`` of the alignment's cluster-robust covariance at its pose (core/covariance.py
  ``sandwich_covariance``, the GICP part of the step's covariance: no floor, nothing added along weak directions);
* the prediction's: what the motion model is observed to miss by along ``d`` (core/covariance.py ``MotionFloor``
  ``weak_sigma``: the root mean square along ``d`` of the recent deviations of the steps not held, growing with
  the steps held in a row).

Where the data's is the larger, the prediction is the better estimate along ``d`` and its position is kept there
(GICP's everywhere else): the decision of a Kalman update that takes the better of two estimates, with both
uncertainties measured, no threshold on the Hessian's shape. On the simulated HDL-64E highway the along-road
information is 0.5-1.5 % of the strongest direction's, above ``odometry.degenerate_ratio`` (0.5 %), and single
alignments slid 0.2-0.6 m along the road while the prediction's deviations there were centimetres. The Hessian's
ratio test (``odometry.degenerate_ratio``) still names degenerate places and holds beyond the gate along them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["held_directions", "merged", "translation_directions"]


def translation_directions(H: np.ndarray, R_map_scan: np.ndarray) -> np.ndarray:
    """(3, 3) rows: the eigen-directions of the translation block of small_gicp's Hessian ``H`` (6, 6), weakest first,
    in the map frame; (0, 3) for a non-finite or zero ``H``."""
    H = np.asarray(H, dtype=np.float64)
    if H.shape != (6, 6) or not np.isfinite(H).all():
        return np.zeros((0, 3))
    w, V = np.linalg.eigh(0.5 * (H[3:, 3:] + H[3:, 3:].T))
    if w[-1] <= 0:
        return np.zeros((0, 3))
    return (np.asarray(R_map_scan, dtype=np.float64) @ V).T


def held_directions(pose: np.ndarray, start: np.ndarray, directions: np.ndarray, limit: float,
                    data_cov: Callable[[], np.ndarray | None],
                    prediction_sigma: Callable[[np.ndarray], float]) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """The ``directions`` (K, 3, map frame) along which ``pose`` (4, 4) slid from ``start`` (4, 4, the prediction) by
    more than ``limit`` m and the data's standard deviation there (``data_cov()``: the alignment's (6, 6) covariance,
    map frame, computed only when a slide needs it; None: no decision) exceeds the prediction's
    (``prediction_sigma(d)``, ``d`` in the map frame; NaN: never measured, no hold).
    -> (held (J, 3), [(data sigma, prediction sigma)] of each held direction)."""
    dirs = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    slide = dirs @ (np.asarray(pose, dtype=np.float64)[:3, 3] - np.asarray(start, dtype=np.float64)[:3, 3])
    beyond = np.abs(slide) > limit
    if not np.isfinite(limit) or not beyond.any():
        return np.zeros((0, 3)), []
    cov = data_cov()
    if cov is None:
        return np.zeros((0, 3)), []
    held, sigmas = [], []
    for d in dirs[beyond]:
        s_data = float(np.sqrt(max(d @ cov[:3, :3] @ d, 0.0)))
        s_pred = float(prediction_sigma(d))
        if np.isfinite(s_pred) and s_data > s_pred:
            held.append(d)
            sigmas.append((s_data, s_pred))
    return (np.array(held) if held else np.zeros((0, 3))), sigmas


def merged(deg: Any, held: np.ndarray, R_map_scan: np.ndarray) -> Any:
    """``deg`` (core/degeneracy.py ``Degeneracy``) with the ``held`` directions (J, 3, map frame) added to its weak ones
    (those within 25 deg of one already there left out), each named by the scan's axis closest to it."""
    from deepbbs_ros.core.degeneracy import Degeneracy

    weak = [np.asarray(w, dtype=np.float64) for w in deg.weak]
    for d in np.asarray(held, dtype=np.float64).reshape(-1, 3):
        if all(abs(float(d @ w)) < 0.9 for w in weak):
            weak.append(d)
    if len(weak) == len(deg.weak):
        return deg
    W = np.array(weak)
    axes = tuple("xyz"[int(np.argmax(np.abs(v)))] for v in W @ np.asarray(R_map_scan, dtype=np.float64))
    return Degeneracy(deg.ratio, W, axes)
