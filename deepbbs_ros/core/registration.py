"""DeepBBS++ registration of one source cloud against one target cloud (no ROS).

``DeepBBSRegistration.register`` reads top-down like kiss-icp's ``register_frame``::

    preprocess  the GICP cloud's voxel grid, crop, ground removal, farthest-point sampling (core/scans.py)
    embed       DGCNN + shared transformer on the moved source and target  (core/model.py)
    match       SoftBBS on the feature distances                            (core/softbbs.py)
    solve       soft map, gamma weights, weighted Procrustes                (core/procrustes.py)
    ... embed/match/solve repeated on the moved source until the increment is small (DeepBBS): the
        network's own object (core/network.py), on a CPU in a worker process (core/network_runner.py,
        core/network_process.py) while this one builds the raw scans' GICP clouds (k-d trees, covariances:
        small_gicp holds the GIL, so a thread would not overlap)
    refine      SoftBBS on xyz, k nearest targets, to convergence           (core/refine.py)
    dense       the same refinement on the voxelised non-ground clouds      (registration.dense_refine)
    polish      precision stage: small_gicp GICP on the dense scans from the estimate (core/polish.py)
    deskew      the same on both scans deskewed with their own stream velocities, when they agree
    verdict     the score of the pose and whether it can be trusted (core/verdict.py), not when GICP finds a
                minimum as good along its weakest direction (core/second_minimum.py)
    global      when it cannot: other start yaws, the best by the verdict kept (core/global_search.py)
    finish      still not trusted: GICP's answer finished on the scans' scene-sized grids, judged again
                (registration.polish_voxel_angle, core/polish.py finish)

With ``good_start=True`` (the caller vouches for ``T_init``: consecutive scans, a fixed mounting, a map from the
last pose) GICP from ``T_init`` runs first and answers alone when the verdict accepts (then coarse to fine, taken when
sure); else the stages above run on the same clouds (core/good_start.py), unless its pose is degenerate along a
direction only the scene's geometry could pin (answered at once, not valid: core/finish_verdict.py).

Defaults (measured by scripts/benchmarks/registration.py): 512 sampled points, 2 deep passes for
the basin, no SoftBBS refinement, and the GICP precision stage on GICP's own clouds for the last
centimetres. The refinement, the dense refinement and more deep passes remain options.

Everything after preprocessing runs in scaled coordinates (``model.scale`` times metres, see
ModelConfig) and translations are scaled back. The result is ``T_target_source``
(p_target = R p_source + t, docs/CONVENTIONS.md), float64. ``register_pair`` (one call, the object kept
between calls) is in core/pair.py.

This class holds the network and calls the stages; each stage is a part of it in a module of its own: the inputs
and the call's start (core/registration_inputs.py), the deep passes and their answer (core/registration_network.py),
the refinements (core/registration_refine.py), the precision stage and deskew (core/registration_precision.py), the
verdict (core/registration_verdict.py); what they share and the result: core/registration_state.py.
"""

from __future__ import annotations

import logging
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core import global_search
from deepbbs_ros.core.good_start import attempt, good_start_gicp, good_start_points
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network import DeepBBSNetwork
from deepbbs_ros.core.network_output import Clock
from deepbbs_ros.core.network_runner import NetworkRunner
from deepbbs_ros.core.registration_inputs import RegistrationInputs
from deepbbs_ros.core.registration_network import NetworkStages
from deepbbs_ros.core.registration_precision import PrecisionStages
from deepbbs_ros.core.registration_refine import RefineStages
from deepbbs_ros.core.registration_state import answer_read, to_result
from deepbbs_ros.core.registration_verdict import VerdictStages
from deepbbs_ros.core.result import RegistrationResult

__all__ = ["RegistrationResult", "DeepBBSRegistration", "good_start_gicp", "good_start_points"]

_log = logging.getLogger(__name__)


class DeepBBSRegistration(RegistrationInputs, NetworkStages, RefineStages, PrecisionStages, VerdictStages):
    """DeepBBS++ registration with one configuration and one network.

    Args:
        config: the whole configuration (defaults if None). When weights are loaded, the model
            section is taken from the checkpoint (it describes the weights).
        weights: checkpoint path; None -> ``config.registration.weights``; "" -> the shipped model
            (``deepbbs_ros/models/deepbbspp_lidar.pt``).
        device: "auto", "cpu", "cuda", "cuda:N"; None -> ``config.registration.device``.
        model: an already built :class:`DeepBBSNet` (tests, training validation); used as is (its
            train/eval mode is the caller's) and moved to ``device``.

    Raises:
        ModelError: the checkpoint is missing, corrupt or does not match.

    One-off costs: on a CPU (``registration.network_process``: auto, 2+ cores) the first :meth:`register` starts
    the network process, reported as the result's ``timings_ms["startup"]`` and left out of its ``"total"``;
    :meth:`warmup` pays it and torch's first-call set-up before the first real scan (the live node does).
    """

    def __init__(
        self,
        config: Config | None = None,
        *,
        weights: str | Path | None = None,
        device: str | None = None,
        model: DeepBBSNet | None = None,
    ) -> None:
        # the model, the checkpoint, the kept target states and the deep passes (core/network.py)
        self.network = DeepBBSNetwork(config, weights=weights, device=device, model=model, stacklevel=3)
        self.config = config = self.network.config
        # where the deep passes run: the network process (registration.network_process) or here (network_runner.py)
        self.runner = NetworkRunner(self.network, config)
        self._searched: deque[bool] = deque(maxlen=global_search.SPECULATE_WINDOW)  # the search ran, last calls
        if self.device.type == "cpu":  # what the first call would import (its nearest-neighbour search; ~0.5 s)
            import scipy.spatial  # noqa: F401

    @property
    def model(self) -> DeepBBSNet:
        return self.network.model

    @property
    def device(self) -> torch.device:
        return self.network.device

    @property
    def metadata(self) -> dict[str, Any]:
        return self.network.metadata

    @property
    def weights_path(self) -> Path | None:
        return self.network.weights_path

    def warmup(self, rounds: int = 2) -> None:
        """Run the network on two random clouds of ``preprocess.num_points`` points ``rounds`` times.

        torch's CPU kernels pick and cache their primitives on the first calls with a new shape (the
        first registration takes seconds, the third ~50 ms): a live node or a benchmark warms up once
        at start instead of on its first real scan.
        """
        rng = np.random.default_rng(0)
        n = self.config.preprocess.num_points
        pts = rng.uniform(-30.0, 30.0, (n, 3)).astype(np.float32)
        for _ in range(rounds):
            self.register(pts, pts[::-1].copy(), preprocessed=True)
        self._searched.clear()  # random clouds: not a hint of what the real ones need
        if self.config.registration.global_search != "off":  # its batches: here (the network process warms its own)
            away = self.runner.state == "running"
            rc = self.config.registration
            self.network.warmup(rounds if away else 0, batches=global_search.batch_sizes(rc)[1 if away else 2],
                                rank_points=global_search.rank_size(rc, n))

    # -- registration ----------------------------------------------------------------------------
    def register(
        self,
        source: np.ndarray,
        target: np.ndarray,
        *,
        T_init: np.ndarray | None = None,
        preprocessed: bool = False,
        good_start: bool = False,
        yaw_search: bool = True,
        polish_check: tuple[int, float] | None = None,
    ) -> RegistrationResult:
        """Estimate ``T_target_source`` (4, 4) float64 moving ``source`` onto ``target``.

        Args:
            source: (N, 3) source scan, metres, sensor frame (raw, or preprocessed when
                ``preprocessed`` is True), or a :class:`PreprocessResult` (its ``points``, its
                ``dense_points`` for the dense refinement and its ``polish_cloud`` for the precision stage).
                Exactly three columns: a KITTI (N, 4) scan (x, y, z, reflectance) is refused, pass
                ``scan[:, :3]``. NaN/Inf rows of a raw scan are dropped (missing returns); a preprocessed
                cloud must be finite (:mod:`deepbbs_ros.core.points`, the check every entry point shares).
            target: (M, 3) target scan, same conventions.
            T_init: (4, 4) initial guess of T_target_source (identity if None).
            preprocessed: skip preprocessing (the clouds are already cropped/sampled; plain arrays carry
                no dense scan, so the dense refinement and the precision stage are skipped).
            good_start: the caller vouches for ``T_init`` (consecutive scans, a fixed mounting, a map from the
                last pose): GICP alone from it on the precision-stage clouds, judged by a stricter verdict
                (``registration.good_start_*``), answers at about GICP's price (``path`` "gicp"); when that verdict
                rejects, GICP does not converge within ``good_start_max_iters`` or moves the start implausibly far,
                GICP coarse to fine from ``T_init`` tries again (core/coarse_rescue.py: taken when sure), then the full
                pipeline runs from ``T_init`` on the clouds already built (unless GICP's finished pose is degenerate:
                answered at once, not valid, core/finish_verdict.py). Without ``T_init`` (or with
                ``preprocessed`` arrays, which have no precision-stage clouds) it is the full pipeline.
            yaw_search: False: no other start yaws for this call (``registration.global_search`` as "off"), the
                given start only; per call, so that callers sharing one registration on several threads do not
                change its configuration.
            polish_check: (iterations, score): the precision stage stops, rejected, when not converged after that
                many iterations with its pose scoring under ``score`` (:func:`core.polish.polish`; a search over
                candidate places, where most are wrong and GICP wanders on them for its whole budget); None: no check.

        Raises:
            RegistrationError: a cloud that is not (N, 3) real numbers, empty, with too few valid points,
                or a ``T_init`` that is not a finite (4, 4) matrix; the message names which.
        """
        clock = Clock(self.device)
        if good_start and T_init is not None:
            first = attempt(self, source, target, T_init, preprocessed, clock)  # GICP from the start first
            if first.result is not None:
                return first.result
            source, target = first.source, first.target  # rejected: the full pipeline on the clouds already built
        if self.network.n_deep and self.runner.state == "unstarted":
            self.runner.process()  # the first call on a CPU: the network process starts (not counted in "total")
            clock.lap("startup")
        st = self._start(source, target, T_init, preprocessed)  # preprocess (raw scans only)
        st.yaw_search, st.polish_check = yaw_search, polish_check
        st.vouched = good_start and T_init is not None  # the caller vouches for the start (core/global_search.py)
        clock.lap("preprocess")
        with torch.inference_mode(), self.network.torch_threads(), answer_read(st):
            self._deep_passes(st, clock)  # embed / match / solve, repeated on the moved source (or sent off)
            self._precision_clouds(st, clock)  # meanwhile: the raw scans' GICP clouds (k-d trees, covariances)
            self._network_result(st, clock)  # the network process's answer
            self._refine(st)  # SoftBBS on xyz (registration.refine)
            clock.lap("refine")
            self._dense_refine(st)  # the same on the voxelised clouds (registration.dense_refine)
            st.inlier_ratio = self._inlier_ratio(st, st.R, st.t)
            clock.lap("dense" if st.iters["dense"] else "refine")
            global_search.before_precision(self, st, clock)  # other start yaws when this answer does not fit
        self._polish(st, clock)  # the GICP precision stage (registration.polish)
        self._deskew(st, clock)  # again on both scans deskewed with their own velocities, if they agree
        self._verdict(st)  # the pose's score and whether it can be trusted (registration.verdict_*)
        st = global_search.retry(self, st, clock)  # still not trusted: the other starts through the precision stage
        self._finish(st, clock)  # still not trusted: GICP's answer finished on the scene's grid, judged again
        self._searched.append(st.starts > 1)
        result = to_result(st, clock)
        if good_start and T_init is not None:
            result.good_start = first.reason
        return result

    @property
    def network_process_state(self) -> str:
        """"running (pid N)", "not started yet", "off" or "failed" (see ``registration.network_process``)."""
        return self.runner.describe()

    def close(self) -> None:
        """Stop the network process, if any (also done when this object is collected or at exit)."""
        self.runner.close()
