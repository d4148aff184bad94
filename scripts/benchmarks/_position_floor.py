"""``--position-floor`` of scripts/benchmarks/covariance.py: other estimates of the position part of the odometry's
prediction floor (core/motion_floor.py ``MotionFloor``), models tried, not shipped.

The floor's motion the model missed is the window's mean square deviation from the constant-velocity prediction ``m``
(``n`` deviations) less the registration noise ``2 g`` it carries (twice a step's mean GICP variance), clipped at 0.
Both estimates below read the ``n`` deviations as ``n m / v ~ chi2(n)`` with ``v = 2 g + s`` (``s``: the missed
variance, not negative), so a window whose deviations are the GICP noise alone still leaves room for what its
sampling error cannot exclude:

* ``posterior``: the posterior median of ``s`` (Jeffreys' prior on ``v``, the posterior cut at ``v >= 2 g``): never
  0, small where ``m`` is about ``2 g`` and about ``m - 2 g`` where ``m`` is well above it;
* ``median``: the median-unbiased estimate of ``v`` (``n m / chi2.median(n)``) less ``2 g``, clipped at 0.

The rotation axes keep the module's estimate (their floor is the sweep's where larger)."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import chdtr, chdtri

__all__ = ["ESTIMATES", "install", "median", "posterior"]


def posterior(mean_square: np.ndarray, noise: np.ndarray, n: int) -> np.ndarray:
    """(k,) the posterior median of the missed variance ``s`` per axis from ``n`` deviations of mean square
    ``mean_square`` that carry the registration noise ``noise`` (``2 g``, variance) (module docstring)."""
    m, g = np.asarray(mean_square, dtype=np.float64), np.asarray(noise, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        above = np.where(g > 0, chdtr(n, n * m / np.where(g > 0, g, 1.0)), 1.0)  # P(v >= 2 g | m)
        v = n * m / chdtri(n, 1.0 - 0.5 * above)
    return np.where(m > 0, np.maximum(v - g, 0.0), 0.0)


def median(mean_square: np.ndarray, noise: np.ndarray, n: int) -> np.ndarray:
    """(k,) the median-unbiased deviations' variance less the noise, clipped at 0 (module docstring)."""
    v = n * np.asarray(mean_square, dtype=np.float64) / chdtri(n, 0.5)
    return np.maximum(v - np.asarray(noise, dtype=np.float64), 0.0)


ESTIMATES = {"posterior": posterior, "median": median}


def install(floormod: Any, name: str) -> None:
    """``MotionFloor._missed``'s position axes from the estimate ``name`` (rotation: the module's)."""
    own, estimate = floormod.MotionFloor._missed, ESTIMATES[name]

    def _missed(self, mean_square: np.ndarray, noise: np.ndarray) -> np.ndarray:
        out = own(self, mean_square, noise)
        out[:3] = estimate(mean_square[:3], noise[:3], len(self._devs))
        return out

    floormod.MotionFloor._missed = _missed
