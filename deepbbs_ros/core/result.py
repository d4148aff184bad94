"""What ``DeepBBSRegistration.register`` returns (no ROS)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from deepbbs_ros.reprs import short_repr

__all__ = ["RegistrationResult"]


@dataclass
class RegistrationResult:
    """The outcome of one registration.

    Attributes:
        T_target_source: (4, 4) float64, p_target = R p_source + t (metres).
        converged: the last stage that ran stopped on its tolerances (not on its iteration cap).
        iterations: {"deep": network passes, "refine": refinement iterations, "dense": dense
            refinement iterations (0 when it did not run), "polish": small_gicp iterations (0 when it
            did not run; counted also when the polish was rejected)}.
        gamma: (N,) float32 confidence of every (preprocessed) source point, from the last stage.
        inlier_ratio: fraction of source points within ``registration.inlier_dist`` metres of a
            target point after alignment.
        temperature: T of the first deep pass (scaled units; 0 when the deep stage is off).
        timings_ms: wall time per stage ("preprocess", "embed", "match", "solve", "refine", "total",
            and "dense" when the dense refinement ran, "polish" / "deskew" when those stages ran).
            "startup": the first call on a CPU starts the network process (seconds: a Python process
            importing torch and loading the checkpoint; :meth:`DeepBBSRegistration.warmup` pays it up front);
            it is reported on its own and not counted in "total", the registration's own time.
        polish: why the polish was accepted ("ok") or rejected, "" when it did not run
            (``registration.polish`` "none", or no dense points).
        deskew: "deskewed" when the precision stage ran on both scans deskewed with their own velocities,
            else why the raw clouds were kept; "" when neither scan was deskewed.
        skew: the skew check's finding on scans with per-point times (``registration.skew_check``,
            core/sweep_skew.py): "rejected: ..." (the motion within a sweep says the pose cannot be within the
            tolerance: not ``valid``) or "passed: ..."; "" when it did not run (no times, or not accepted before it).
        source, target: the (preprocessed) clouds that were registered, (N, 3)/(M, 3) float32: the sampled points;
            on the "gicp" path the spread subsets of the GICP clouds that its verdict scores.
        valid: the verdict: the pose can be trusted (``probability >= registration.verdict_probability``; on the
            "gicp" path ``registration.good_start_probability``).
        score: the pose's fitness (core/verdict.py): share of the sampled source points within
            ``registration.verdict_dist`` of the target's precision-stage cloud under the pose (on the "gicp" path:
            of its spread subset of the source's GICP voxels).
        probability: the verdict: the calibrated probability (0..1) that the pose is within 1 degree / 0.3 m of
            the truth (core/verdict.py: fitted on simulated pairs of every sensor, mount and place).
        starts: start yaws tried (1: the given start; more when the global search ran, core/global_search.py).
        path: which path answered: "gicp" (``good_start``: GICP from the given start, accepted by its stricter
            verdict), "deepbbs" (the deep passes from the given start, then the precision stage) or "search" (the
            any-start search ran: other start yaws, then shifted starts).
        good_start: ``good_start`` only: "accepted", "accepted, sure, within the coarse try's reach (...)" (GICP
            converged beyond the good start's limits, core/good_start.py), "accepted after coarse to fine (why GICP
            from the start was not)" (core/coarse_rescue.py), "not valid: degenerate along ..." (``path`` "gicp",
            not ``valid``: core/finish_verdict.py), or why the GICP-first path was not (then ``path`` is
            "deepbbs" or "search" and ``timings_ms["good_start"]`` is what the attempt cost); "" otherwise.
    """

    __repr__ = short_repr  # one readable line: arrays as shape and dtype (deepbbs_ros/reprs.py)

    T_target_source: np.ndarray
    converged: bool
    iterations: dict[str, int]
    gamma: np.ndarray
    inlier_ratio: float
    temperature: float
    timings_ms: dict[str, float]
    source: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3), np.float32))
    target: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3), np.float32))
    polish: str = ""
    deskew: str = ""
    skew: str = ""
    valid: bool = False
    score: float = float("nan")
    starts: int = 1
    path: str = "deepbbs"
    good_start: str = ""
    probability: float = float("nan")
