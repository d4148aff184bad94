"""Degenerate places and the motion model's gate for the odometry (no ROS import).

Degeneracy: in a corridor, a tunnel or on a straight road with little beside it, scan-to-map GICP cannot tell how
far the sensor moved along the axis; on an open field, nor across the plane. Its Gauss-Newton Hessian says so: the
translation block ``H_tt`` of small_gicp's Hessian (right perturbation ``T exp(xi)``, ``xi = [rot, trans]``, the
translation in the scan's frame) has an eigenvalue far below its largest along each such direction. The ratio
``lambda / lambda_max`` does not scale with the point count, the noise or the cost's scale (all of them scale the
whole block), so one threshold (``odometry.degenerate_ratio``) means about the same on every sensor; a sparse
scan's noisy point covariances add some spurious information along a weak direction (a synthetic corridor: ratio
3e-3 from 20,000 points, 5e-3 from 6,000, 4e-2 from 600), so on very sparse scans fewer places are called
degenerate. Along a weak
direction GICP's answer is where the start and the sampling left it, not a measurement: where it moved the pose
along it by more than the motion model's gate, :func:`hold` keeps the start's (the motion model's) position along
it and GICP's everywhere else (the update projected onto the well-constrained subspace, as in Zhang, Kaess and
Singh's solution remapping, ICRA 2016). Within the gate GICP's answer stands: a hand-held sensor's prediction is
worse than the little a weak direction still tells.

Gate: :class:`MotionGate` is KISS-ICP's adaptive threshold turned into a check: the root mean square of the last
steps' deviations from the constant-velocity prediction (what the motion model is observed to miss by on this
sensor and this carrier), and a step deviating more than ``odometry.gate_sigmas`` times that is suspect: DeepBBS++
checks it (core/odometry.py) instead of the map silently taking a jump of metres.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Degeneracy", "MotionGate", "analyse", "deviation", "hold"]

_AXES = "xyz"


@dataclass
class Degeneracy:
    """What a GICP Hessian says about the place.

    ratio: smallest over largest eigenvalue of the translation block (1: every direction as well constrained).
    weak: (K, 3) float64 unit directions, in the map frame, with ``lambda / lambda_max`` below the threshold (K = 0:
        not degenerate; 1: corridor-like; 2: open-field-like).
    axes: the scan's (sensor frame) axis closest to each weak direction, e.g. "x".
    """

    ratio: float = 1.0
    weak: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    axes: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """"" when well constrained, else e.g. "corridor-like, weak axis x" (the scan's axes)."""
        if not self.axes:
            return ""
        kind = "corridor-like" if len(self.axes) == 1 else "open-field-like"
        return f"{kind}, weak axis {' '.join(self.axes)} (ratio {self.ratio:.1e})"


def analyse(H: np.ndarray, R_map_scan: np.ndarray, threshold: float) -> Degeneracy:
    """The weak translation directions of small_gicp's Hessian ``H`` (6, 6) at the pose whose rotation is
    ``R_map_scan`` (3, 3): eigen-directions of ``H[3:, 3:]`` with ``lambda < threshold * lambda_max``. A
    non-finite or zero ``H`` gives the well-constrained default (nothing to say)."""
    H = np.asarray(H, dtype=np.float64)
    if H.shape != (6, 6) or not np.isfinite(H).all():
        return Degeneracy()
    Ht = 0.5 * (H[3:, 3:] + H[3:, 3:].T)
    w, V = np.linalg.eigh(Ht)
    if w[-1] <= 0:
        return Degeneracy()
    ratio = float(max(w[0], 0.0) / w[-1])
    k = int(np.sum(w < threshold * w[-1]))
    weak_scan = V[:, :k].T  # (K, 3) in the scan's frame
    axes = tuple(_AXES[int(np.argmax(np.abs(v)))] for v in weak_scan)
    return Degeneracy(ratio, weak_scan @ np.asarray(R_map_scan, dtype=np.float64).T, axes)


def hold(pose: np.ndarray, start: np.ndarray, weak: np.ndarray, limit: float = 0.0) -> np.ndarray:
    """``pose`` (4, 4) with its position along each ``weak`` direction (K, 3), map frame, put back to ``start``'s
    where it moved away from it by more than ``limit`` metres (the motion model's gate: within it, GICP's little
    information along the direction agrees with the motion model and is kept)."""
    out = np.array(pose, dtype=np.float64, copy=True)
    if len(weak):
        along = weak @ (out[:3, 3] - np.asarray(start, dtype=np.float64)[:3, 3])  # (K,)
        along[np.abs(along) <= limit] = 0.0
        out[:3, 3] -= weak.T @ along
    return out


class MotionGate:
    """How far a step may deviate from the constant-velocity prediction before it is suspect.

    ``limit() = max(sigmas * rms(last window deviations), floor)``, inf until ``min_steps`` deviations were seen
    (KISS-ICP's adaptive threshold: derived from the motion model's observed error, no constant per sensor; the
    ``floor``, a tenth of the map voxel, keeps a perfectly predictable drive from flagging centimetres)."""

    def __init__(self, sigmas: float, window: int, floor: float, min_steps: int = 3) -> None:
        self.sigmas, self.floor, self.min_steps = float(sigmas), float(floor), int(min_steps)
        self._dev: deque[float] = deque(maxlen=max(1, int(window)))

    def limit(self) -> float:
        """Metres; inf while too few steps were seen or with ``sigmas`` 0 (the gate off)."""
        if self.sigmas <= 0 or len(self._dev) < self.min_steps:
            return float("inf")
        return max(self.sigmas * float(np.sqrt(np.mean(np.square(self._dev)))), self.floor)

    def update(self, deviation: float) -> None:
        if np.isfinite(deviation):
            self._dev.append(float(deviation))


def deviation(pose: np.ndarray, prediction: np.ndarray) -> float:
    """Metres between the positions of ``pose`` and ``prediction`` (4, 4)."""
    return float(np.linalg.norm(np.asarray(pose)[:3, 3] - np.asarray(prediction)[:3, 3]))
