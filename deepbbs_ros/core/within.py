"""How probable it is that a pose lies within the tolerance, from its own covariance (no ROS).

The calibrated verdict (core/calibrated.py) asks whether the fit is consistent: the source's surfaces lie on the
target's, tightly, and nothing lands in the target's free space. A pose that can slide (along a corridor, a straight
road, a wall) is consistent anywhere along the slide, so consistency alone cannot say it is right. The pose's
covariance can: core/covariance.py's cluster-robust, leave-one-cell-out covariance of the GICP solution (the
localization's, widened as Student's t with each direction's effective number of cells), the data's own: nothing is
added along a direction the Hessian leaves weak (the localization adds its start's spread there, the answer anywhere
within GICP's reach; a verdict asks what the scans pin, and with that spread right poses in corridors were rejected
as well, docs/sensors.md). Then

    P(within) = P(|dt| <= 0.3 m and |dtheta| <= 1 degree),  (dt, dtheta) ~ N(0, covariance),

the share of a fixed set of :data:`SAMPLES` standard normal draws (deterministic; its standard error is at most
0.008) that the covariance's square root maps within the tolerance (``registration.success_trans``,
``success_rot_deg``: the verdict's own definition of right). The verdict reports P(consistent) x P(within)
(``registration.verdict_within``, off by default: docs/sensors.md). No constant is fitted: the covariance is
core/covariance.py's, unchanged. Cost: a nearest-neighbour search of every source voxel and the cells' terms, 3-9 ms
a pose (one thread); the verdict computes it only where the calibrated probability alone would accept.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core import covariance

__all__ = ["SAMPLES", "pose_covariance", "probability", "within"]

#: standard normal draws (6 each) of :func:`probability`: fixed, so the same covariance gives the same answer
SAMPLES = 4096
_Z = np.random.default_rng(20261207).standard_normal((SAMPLES, 6))


def pose_covariance(source: Any, target: Any, T: np.ndarray, corr: float, threads: int = 1,
                    weak: bool = False) -> np.ndarray | None:
    """(6, 6) covariance (core/covariance.py's convention: ``[dt, dtheta]``, target frame) of the pose ``T`` (4, 4)
    ``T_target_source`` of the precision stage's clouds ``source`` and ``target`` (core.polish.PolishCloud), from
    GICP's pairs within ``corr`` m at the pose; ``weak``: with the answer spread over GICP's reach along a weak
    translation direction (the localization's; not the verdict's). None without pairs or with a singular Hessian (a
    direction nothing pins)."""
    try:
        pairs = covariance.matched_pairs(source, target, T, corr, threads, covariance.LOCALIZATION_MAX_POINTS)
    except (RuntimeError, ValueError, IndexError):  # a cloud without normals
        return None
    return covariance.sandwich_covariance(pairs, T, 1.0, weak_sigma=corr / 3.0 ** 0.5 if weak else 0.0,
                                          student=True)


def probability(cov: np.ndarray | None, trans: float = 0.3, rot_deg: float = 1.0) -> float:
    """P(|dt| <= ``trans`` m and |dtheta| <= ``rot_deg`` degrees) for ``[dt, dtheta]`` ~ N(0, ``cov``) (6, 6);
    0 for no covariance (None, or not finite)."""
    if cov is None or not np.all(np.isfinite(cov)):
        return 0.0
    w, U = np.linalg.eigh(0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).T))
    e = (_Z * np.sqrt(np.maximum(w, 0.0))) @ U.T
    ok = (np.einsum("ij,ij->i", e[:, :3], e[:, :3]) <= trans * trans) & \
         (np.einsum("ij,ij->i", e[:, 3:], e[:, 3:]) <= np.radians(rot_deg) ** 2)
    return float(ok.mean())


def within(source: Any, target: Any, T: np.ndarray, rc: Any, threads: int = 1, weak: bool = False) -> float:
    """:func:`probability` of the pose ``T`` (4, 4) of the precision stage's clouds, paired within
    ``rc.polish_max_corr_dist`` (the registration section), the tolerance ``rc.success_trans`` /
    ``rc.success_rot_deg``."""
    cov = pose_covariance(source, target, T, rc.polish_max_corr_dist, threads, weak)
    return probability(cov, rc.success_trans, rc.success_rot_deg)
