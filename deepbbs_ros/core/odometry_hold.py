"""The odometry's hold: where the data pin a direction less than the prediction does, the prediction's position stays
(no ROS import).

A step whose position slid from the constant-velocity prediction beyond the motion model's gate (core/degeneracy.py
``MotionGate``) along an eigen-direction ``d`` of the alignment's translation Hessian is one of two things: the
motion changed (the data say so, precisely) or the alignment slid along a direction the data barely pin (a straight
road, a corridor). The two standard deviations along ``d`` tell them apart:

* the data's: ``sqrt(d^T Sigma d)`` of the alignment's cluster-robust covariance at its pose (core/covariance.py
  ``sandwich_covariance``, the GICP part of the step's covariance: no floor, nothing added along weak directions),
  and at least what an error of the cost's gradient shared by every cell moves the pose by along ``d``: the scan's
  and the map's sampling of the same surfaces (a spinning sensor's rings, the voxel grid) bias the gradient alike in
  every direction, and a bias does not average down over cells as the sandwich's independent errors do, so it
  moves the pose by it over the information along ``d``: ``sigma_strong * lambda_max / lambda_d``, with
  ``sigma_strong`` the covariance's standard deviation along the best-pinned direction (``lambda_max``). In a
  synthetic featureless corridor the sandwich's own figure along the axis was 5 mm and the slide it allowed 0.12 m;
  the bias term made it 7.5 cm;
* the prediction's: what the motion model is observed to miss by along ``d`` (core/motion_floor.py ``MotionFloor``
  ``weak_sigma``: the root mean square along ``d`` of the recent deviations of the steps not held, growing with
  the steps held in a row), and at least the last step's deviation along ``d`` (``last_deviation``: the constant
  velocity carries it into this prediction; without it a slide the velocity had absorbed was held against the next
  step's correction, 1.7 m off on a simulated VLP-16 highway).

Where the data's is the larger, the prediction is the better estimate along ``d``, and the position along it becomes
the two estimates' weighted mean (:func:`blend`: a Kalman update along ``d``, weights the inverse variances; GICP's
position everywhere else): with the data's many times the prediction's that is the prediction's position (a
featureless corridor), with the two alike it moves half way. No threshold on the Hessian's shape. A hold that kept the
prediction's position outright locked the velocity along the road at whatever it was when the holds began (on the
simulated HDL-64E highway 0.1 m a scan short for 19 scans, 1.95 m behind at the end): the weighted mean lets the
data's little information through, and the prediction's standard deviation grows with the steps held in a row.

Only a slide beyond the gate is looked at (the data's covariance costs a pass over the pairs; within the gate GICP's
answer stands). On the simulated HDL-64E highway the along-road information is 0.5-1.5 % of the strongest
direction's, above ``odometry.degenerate_ratio`` (0.5 %), and single alignments slid 0.2-0.6 m along the road while
the prediction's deviations there were centimetres. The Hessian's ratio test (``odometry.degenerate_ratio``) still
names degenerate places and holds the prediction's position beyond the gate along them (on a synthetic featureless
corridor, 5.8 m driven, the statistical test alone ends 0.15 m off, with the ratio test as well 0.15 m, with neither
4.33 m).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["blend", "data_sigmas", "held_directions", "merged", "translation_directions"]


def translation_directions(H: np.ndarray, R_map_scan: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The eigen-directions of the translation block of small_gicp's Hessian ``H`` (6, 6), weakest first: (K, 3) rows
    in the map frame and their (K,) eigenvalues; K = 0 for a non-finite or zero ``H``."""
    H = np.asarray(H, dtype=np.float64)
    if H.shape != (6, 6) or not np.isfinite(H).all():
        return np.zeros((0, 3)), np.zeros(0)
    w, V = np.linalg.eigh(0.5 * (H[3:, 3:] + H[3:, 3:].T))
    if w[-1] <= 0:
        return np.zeros((0, 3)), np.zeros(0)
    return (np.asarray(R_map_scan, dtype=np.float64) @ V).T, np.maximum(w, w[-1] * 1e-12)


def data_sigmas(cov: np.ndarray, directions: np.ndarray, eigenvalues: np.ndarray) -> np.ndarray:
    """(K,) m: the data's standard deviation along each of the Hessian's eigen-``directions`` (K, 3, map frame; their
    ``eigenvalues`` (K,)) from the alignment's covariance ``cov`` (6, 6, map frame): the larger of the covariance's
    own and the shared gradient error's, ``sigma_strong * lambda_max / lambda`` (the module docstring)."""
    dirs = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    lam = np.asarray(eigenvalues, dtype=np.float64).reshape(-1)
    own = np.sqrt(np.maximum(np.einsum("ki,ij,kj->k", dirs, np.asarray(cov)[:3, :3], dirs), 0.0))
    strong = own[int(np.argmax(lam))]
    return np.maximum(own, strong * lam.max() / lam)


def held_directions(pose: np.ndarray, start: np.ndarray, directions: tuple[np.ndarray, np.ndarray], limit: float,
                    data_cov: Callable[[], np.ndarray | None],
                    prediction_sigma: Callable[[np.ndarray], float]) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """The Hessian's eigen-``directions`` ((K, 3) map frame, (K,) eigenvalues: :func:`translation_directions`) along
    which ``pose`` (4, 4) slid from ``start`` (4, 4, the prediction) by more than ``limit`` m and the data's standard
    deviation (:func:`data_sigmas`; ``data_cov()``: the alignment's (6, 6) covariance, map frame, computed only when a
    slide needs it; None: no decision) exceeds the prediction's (``prediction_sigma(d)``, ``d`` in the map frame; NaN:
    never measured, no hold). -> (held (J, 3), [(data sigma, prediction sigma)] of each held direction)."""
    dirs, lam = directions
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    slide = dirs @ (np.asarray(pose, dtype=np.float64)[:3, 3] - np.asarray(start, dtype=np.float64)[:3, 3])
    beyond = np.abs(slide) > limit
    if not np.isfinite(limit) or not beyond.any():
        return np.zeros((0, 3)), []
    cov = data_cov()
    if cov is None:
        return np.zeros((0, 3)), []
    held, sigmas = [], []
    for d, s_data in zip(dirs[beyond], data_sigmas(cov, dirs, lam)[beyond], strict=True):
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


def blend(pose: np.ndarray, start: np.ndarray, held: np.ndarray, sigmas: list[tuple[float, float]]) -> np.ndarray:
    """``pose`` (4, 4) with its position along each ``held`` direction (J, 3, map frame) the weighted mean of its own
    and ``start``'s, the weights the inverse variances of ``sigmas`` ([(data, prediction)] m, per direction)."""
    out = np.array(pose, dtype=np.float64, copy=True)
    for d, (s_data, s_pred) in zip(np.asarray(held, dtype=np.float64).reshape(-1, 3), sigmas, strict=True):
        gain = s_pred ** 2 / (s_pred ** 2 + s_data ** 2)  # the data's share
        out[:3, 3] -= (1.0 - gain) * float(d @ (out[:3, 3] - np.asarray(start, dtype=np.float64)[:3, 3])) * d
    return out
