"""What one GICP run of the precision stage comes to (core/polish.py; no ROS): :class:`PolishResult`, and
:func:`outcome`, which judges small_gicp's answer by the stage's rules (converged, enough correspondences, within
``polish_max_trans`` / ``polish_max_rot_deg`` of the start)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.config import RegistrationConfig
from deepbbs_ros.core.polish_cloud import MIN_POLISH_POINTS
from deepbbs_ros.reprs import short_repr

__all__ = ["PolishResult", "outcome"]


@dataclass
class PolishResult:
    """The outcome of one polish.

    Attributes:
        T_target_source: (4, 4) float64; the polished estimate when ``applied``, else ``T_init``.
        applied: the polish was accepted.
        reason: "ok", or why it was rejected ("not converged", "moved 2.4 m > 2.0 m", ...).
        converged: small_gicp's own convergence flag (False when it did not run).
        iterations: small_gicp iterations (0 when it did not run).
        num_inliers: correspondences within ``polish_max_corr_dist`` at the end.
        delta_trans_m, delta_rot_deg: how far the polish moved the estimate (also when rejected).
        timings_ms: {"prepare": voxel grid + trees + covariances (0 for prepared clouds), "align", "total"}.
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    T_target_source: np.ndarray
    applied: bool
    reason: str
    converged: bool = False
    iterations: int = 0
    num_inliers: int = 0
    delta_trans_m: float = 0.0
    delta_rot_deg: float = 0.0
    timings_ms: dict[str, float] = field(default_factory=dict)
    check_score: float = float("nan")  # the score at the check (polish(..., check=...)); nan when none was made
    #: small_gicp's (H (6, 6), error, inliers) at its last linearisation (core/covariance.py reads a pose's covariance
    #: from them); None when it did not run
    hessian: tuple[np.ndarray, float, int] | None = None


def outcome(res: Any, T_init: np.ndarray, cfg: RegistrationConfig, corr: float, T_base: np.ndarray | None = None,
            iterations: int | None = None, check_score: float = float("nan"), stop: str = "",
            times: tuple[float, float, float] | None = None) -> PolishResult:
    """small_gicp's answer ``res`` from ``T_init`` (4, 4; ``T_base @ T_init`` when the target is a map crop's view,
    answered in the crop's frame), correspondences within ``corr`` m -> :class:`PolishResult`: accepted, or why not
    (``stop``: why the check stopped it, else small_gicp's own convergence, its correspondences, the move's limits).
    ``iterations``: over all legs (``res.iterations`` when None); ``times``: perf_counter at the start, after the
    preparation and after the alignment (timings 0 when None)."""
    t0, t1, t2 = times or (0.0, 0.0, 0.0)
    iterations = int(res.iterations) if iterations is None else iterations
    T = np.asarray(res.T_target_source, dtype=np.float64).copy()
    if T_base is not None:
        T = np.linalg.solve(T_base, T)
    dT = np.linalg.inv(T_init) @ T
    d_trans = float(np.linalg.norm(T[:3, 3] - T_init[:3, 3]))
    d_rot = float(np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))
    if stop:
        reason = stop
    elif not res.converged:
        reason = f"not converged in {iterations} iterations"
    elif int(res.num_inliers) < MIN_POLISH_POINTS:
        reason = f"only {res.num_inliers} correspondences within {corr:.2f} m"
    elif 0 < cfg.polish_max_trans < d_trans:
        reason = f"moved {d_trans:.2f} m > polish_max_trans {cfg.polish_max_trans} m"
    elif 0 < cfg.polish_max_rot_deg < d_rot:
        reason = f"turned {d_rot:.2f} deg > polish_max_rot_deg {cfg.polish_max_rot_deg} deg"
    else:
        reason = "ok"
    applied = reason == "ok"
    return PolishResult(
        T_target_source=T if applied else T_init.copy(),
        applied=applied,
        reason=reason,
        converged=bool(res.converged),
        iterations=iterations,
        num_inliers=int(res.num_inliers),
        delta_trans_m=d_trans,
        delta_rot_deg=d_rot,
        check_score=check_score,
        timings_ms={"prepare": (t1 - t0) * 1e3, "align": (t2 - t1) * 1e3, "total": (t2 - t0) * 1e3},
        hessian=(np.asarray(res.H, dtype=np.float64), float(res.error), int(res.num_inliers)),
    )
