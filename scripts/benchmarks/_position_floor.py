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


def position_line(steps: list, chain: list, floors: list) -> str:
    """``--pose``'s ``position`` line of a drive (scripts/benchmarks/covariance.py ``odometry_rows``), x, y, z of the
    previous scan's axes, mm, over the steps after the first: the steps' root mean square error; the published
    standard deviation's (root mean square of the covariance's diagonal); the consecutive steps' difference's root
    mean square over ``sqrt(2)`` (what the deviations from a constant velocity hold when the steps' errors are
    independent and the true motion constant: the floor's view of the error); the share of steps whose prediction
    floor is under 1 mm."""
    from deepbbs_ros.core.covariance import pose_error

    err = np.array([d[:3] for d, _ in steps[1:]])
    sd = np.array([np.diag(c)[:3] for _, c in steps[1:]])
    diff = np.array([pose_error(a[1], b[1])[:3] for a, b in zip(chain[1:-1], chain[2:])])
    low = []
    for (T_prev, *_), fl in zip(chain[1:], floors[1:]):
        B = np.asarray(T_prev, dtype=np.float64)[:3, :3]
        low.append(np.sqrt(np.maximum(np.diag(B.T @ np.asarray(fl)[:3, :3] @ B), 0.0)) < 1e-3)

    def mm(x: np.ndarray) -> str:
        return ", ".join(f"{v * 1e3:.1f}" for v in x)

    return (f"position (x, y, z; mm): step error rms {mm(np.sqrt(np.mean(err ** 2, 0)))}; published sd rms "
            f"{mm(np.sqrt(np.mean(sd, 0)))}; consecutive steps' difference rms / sqrt 2 "
            f"{mm(np.sqrt(np.mean(diff ** 2, 0) / 2))}; prediction floor under 1 mm on "
            + ", ".join(f"{v:.0%}" for v in np.mean(low, 0)) + " of the steps")
