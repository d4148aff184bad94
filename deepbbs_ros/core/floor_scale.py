"""An innovation-based adaptive scale of the odometry's rotation floor (no ROS import; ``odometry.sweep_floor``
``adaptive`` or ``adaptive_bound``, off by default: docs/node.md#covariances has the figures).

The odometry registers each scan from the constant-velocity prediction ``T_{k-1} D_{k-1}`` (``D_{k-1}`` the last
step's motion); the innovation ``nu_k`` is the rotation part of ``log(prediction^-1 T_k)``, what the registration
moved the pose from its prediction (core/motion_floor.py's deviations). Per rotation axis of the scan, with each
step's motion ``D_j = M_j + eps_j`` (the true motion and the step's error):

    nu_k = (M_k - M_{k-1}) + eps_k - eps_{k-1}
    E[nu_k^2] = q_k + s_k + s_{k-1} - 2 c_k

``q_k`` the variance of the true motion's change, ``s_j = g_j + f_j`` a step's variance (``g_j`` its GICP part, which
the step's pairs give; ``f_j`` its floor), ``c_k`` the covariance of consecutive step errors. The scale ``lam`` of the
floor (``f_j -> lam f_j``, ``f_j`` the fixed floor's variance, :class:`~deepbbs_ros.core.motion_floor.MotionFloor`)
is the innovation covariance matching of adaptive Kalman filtering (Mehra 1970; Myers and Tapley 1976) under two
premises: ``q_k = 0`` (all the innovation the GICP parts leave is laid on the steps' floors: where the body sways the
motion's change is counted as step error, and the scale comes out too large) and ``c_k = 0`` (independent steps:
where consecutive steps share an error, as a map built from bent scans hands on, ``c_k > 0`` and the innovation
shows less of it than the steps carry, so the scale comes out too small). Then per axis

    S_k(lam) = g_k + g_{k-1} + lam (f_k + f_{k-1})

and the normalized innovation squared (NIS) ``sum_i nu_{k,i}^2 / S_{k,i}(lam)`` is chi-square with 3 degrees of
freedom. ``lam`` is the root of ``(1 / N) sum_k NIS_k(lam) = 3`` over the last ``N`` innovations (the mean NIS of
the window equal to its expectation: ``adaptive``), one scale for the rotation block so that the floor keeps its
per-axis shape; 0 where the GICP parts alone leave the mean NIS at or under 3; an axis without a floor has nothing to
scale and is left out with its degree of freedom. ``adaptive_bound``: the largest scale the window does not reject as
too small at 2.5 % (its NIS sum equal to ``chi2.ppf(0.025, 3 N)``). The window is
the floor's own (``MOTION_WINDOW`` steps, KISS-ICP's adaptive threshold's idea: the motion model's recent error);
the mean NIS of ``N`` innovations has a relative standard deviation of about ``1 / sqrt(N)`` (per axis a mean of
``N`` squared unit normals whose neighbours correlate by -1/2, sharing a step: variance ``2 (1 + 2 / 4) / N``, a third
of it over three axes), which is how far one window's scale moves about its truth. Until two consecutive steps with
a floor and GICP parts are known the scale is 1 (the fixed floor). It scales a variance: the floor's standard
deviations move by ``sqrt(lam)``."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

__all__ = ["MODES", "InnovationScale"]

#: ``odometry.sweep_floor``: the fixed floor, the innovation-matched scale, its 2.5 % bound
MODES = ("fixed", "adaptive", "adaptive_bound")


class InnovationScale:
    """The running scale of the rotation floor's variance from the last ``window`` innovations (module docstring).

    Per step: :meth:`add_step` with the step's innovation and its fixed floor (before the step's covariance), then
    :meth:`add_noise` with its GICP part (after it); :meth:`scale` reads the innovations whose two steps are known."""

    def __init__(self, window: int, bound: bool = False) -> None:
        self.window, self.bound = int(window), bool(bound)
        self._steps: Any = deque(maxlen=self.window + 1)  # [nu (3,), f (3,), g (3,) or None]; None: no innovation

    def add_step(self, nu: np.ndarray | None, floor_var: np.ndarray | None) -> None:
        """A step's rotation innovation ``nu`` (3,) rad and its fixed floor's variance ``floor_var`` (3,) rad^2;
        None (the first motion, no prediction) breaks the chain of consecutive steps."""
        if nu is None or floor_var is None:
            self._steps.append(None)
        else:
            self._steps.append([np.asarray(nu, dtype=np.float64), np.asarray(floor_var, dtype=np.float64), None])

    def add_noise(self, gicp_var: np.ndarray) -> None:
        """The last step's GICP variance per rotation axis (3,) rad^2."""
        if self._steps and self._steps[-1] is not None:
            self._steps[-1][2] = np.asarray(gicp_var, dtype=np.float64)

    def _pairs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(nu, a, b), each (n, 3): the innovations whose step and previous step are known, ``S = a + lam b``."""
        nu, a, b = [], [], []
        steps = list(self._steps)
        for prev, cur in zip(steps[:-1], steps[1:]):
            if prev is None or cur is None or prev[2] is None or cur[2] is None:
                continue
            nu.append(cur[0])
            a.append(cur[2] + prev[2])
            b.append(cur[1] + prev[1])
        return np.array(nu), np.array(a), np.array(b)

    def scale(self) -> float:
        """The floor's variance scale ``lam`` (1 before any innovation with both steps known)."""
        nu, a, b = self._pairs()
        if not len(nu):
            return 1.0
        return nis_root(nu, a, b, bound=self.bound)


def nis_root(nu: np.ndarray, a: np.ndarray, b: np.ndarray, bound: bool = False) -> float:
    """``lam >= 0`` with ``mean sum_i nu_ki^2 / (a_ki + lam b_ki)`` over the innovations ``k`` (rows) equal to the
    axes' count: the mean NIS at its expectation, decreasing in ``lam``; ``bound``: the NIS sum at its 2.5 % quantile
    instead. Only the axes with a floor (``b > 0``) count, with their own degrees of freedom: an axis without one (the
    prediction's floor at 0 where the deviations are all registration noise) has nothing to scale. 0 where ``lam = 0``
    leaves the NIS at or under its target, or where no axis has a floor."""
    keep = np.asarray(b) > 0
    if not keep.any():
        return 0.0
    nu2, a, b = np.square(nu)[keep], np.maximum(np.asarray(a)[keep], 1e-30), np.asarray(b)[keep]
    n = len(nu2)  # the degrees of freedom: one per axis and innovation
    target = 1.0
    if bound:
        from scipy.stats import chi2

        target = float(chi2.ppf(0.025, n)) / n

    def excess(lam: float) -> float:
        return float(np.mean(nu2 / (a + lam * b))) - target

    if excess(0.0) <= 0.0:
        return 0.0
    hi = 1.0
    while excess(hi) > 0.0:
        hi *= 4.0
    from scipy.optimize import brentq

    return float(brentq(excess, 0.0, hi, xtol=1e-6, rtol=1e-6))
