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
    verdict     the score of the pose and whether it can be trusted (core/verdict.py)
    global      when it cannot: other start yaws, the best by the verdict kept (core/global_search.py)

With ``good_start=True`` (the caller vouches for ``T_init``: consecutive scans, a fixed mounting, a map from the
last pose) GICP from ``T_init`` runs first and answers alone when the verdict accepts (then coarse to fine, taken when
sure); else the stages above run on the same clouds (core/good_start.py).

Defaults (measured by scripts/benchmarks/registration.py): 512 sampled points, 2 deep passes for
the basin, no SoftBBS refinement, and the GICP precision stage on GICP's own clouds for the last
centimetres. The refinement, the dense refinement and more deep passes remain options.

Everything after preprocessing runs in scaled coordinates (``model.scale`` times metres, see
ModelConfig) and translations are scaled back. The result is ``T_target_source``
(p_target = R p_source + t, docs/CONVENTIONS.md), float64. ``register_pair`` (one call, the object kept
between calls) is in core/pair.py.
"""

from __future__ import annotations

import contextlib
import logging
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core import global_search, pair_deskew, verdict
from deepbbs_ros.core.good_start import attempt, good_start_gicp, good_start_points
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network import Clock, DeepBBSNetwork, NetworkOutput, matrix, orthonormalize, worker_share
from deepbbs_ros.core.network_runner import NetworkRunner
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.polish import PolishCloud, polish, threads_or_all
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.procrustes import apply_transform
from deepbbs_ros.core.refine import NeighbourSearch, refine
from deepbbs_ros.core.result import RegistrationResult
from deepbbs_ros.core.scans import deskew_prepared, polish_cloud, prepare_scan

__all__ = ["RegistrationResult", "DeepBBSRegistration", "good_start_gicp", "good_start_points"]

_log = logging.getLogger(__name__)


class DeepBBSRegistration:
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

    # -- preprocessing ---------------------------------------------------------------------------
    def preprocess(self, points: np.ndarray, times: np.ndarray | None = None, stamp_ns: int | None = None,
                   motion: tuple[np.ndarray, float] | None = None, *, defer: bool = False,
                   lazy: bool = False, driver: str | None = None) -> PreprocessResult:
        """Raw scan (N, 3) metres (per-point ``times`` (N,) s since ``stamp_ns``, a known ``motion`` of the
        sensor) -> :class:`PreprocessResult` with its precision-stage cloud (:func:`core.scans.prepare_scan`).
        Everything a scan needs is here: a scan preprocessed once serves as source and as target (odometry, the
        node). ``defer``: the precision-stage cloud's k-d tree and covariances wait (:meth:`PolishCloud.complete`).
        ``lazy``: the network's points (ground removal, FPS) wait for their first read (a good start may never need
        them; :meth:`PreprocessResult.sample`). ``driver``: the driver that published the scan
        (``msg_adapters.layouts.recognise_driver``), which settles ``preprocess.sensor`` "auto".
        """
        return prepare_scan(self.config, points, times, stamp_ns, motion, defer=defer, threads=self.gicp_threads(),
                            lazy=lazy, driver=driver)

    def polish_cloud(self, points: np.ndarray, *, defer: bool = False) -> PolishCloud:
        """Raw scan (N, 3) -> its precision-stage cloud (``registration.polish_*``, the preprocess crop)."""
        return polish_cloud(self.config, points, defer=defer, threads=self.gicp_threads())

    def deskew_scan(self, pre: PreprocessResult, motion: tuple[np.ndarray, float]) -> PreprocessResult:
        """A copy of ``pre`` with ``deskewed_cloud``, its precision-stage cloud deskewed with the scan's own
        velocity ``motion`` = (``T_a_b`` (4, 4), seconds from a to b) (:func:`core.scans.deskew_prepared`;
        ``core.deskew.StreamDeskew`` estimates it from the previous scan of the stream)."""
        return deskew_prepared(self.config, pre, motion, threads=self.gicp_threads())

    @property
    def defers_precision(self) -> bool:
        """Raw scans' precision-stage k-d trees and covariances are best left to :meth:`register`, which builds
        them while the network process runs the passes (``preprocess(..., defer=True)``; the node's inputs)."""
        return self.network.n_deep > 0 and self.runner.state in ("unstarted", "running")

    def gicp_threads(self) -> int:
        """small_gicp threads for a call made now: ``registration.polish_threads``, or (0) every core but the
        one the network process computes on while it works on a request (small_gicp holds the GIL, so one
        small_gicp call runs at a time in this process: cores = its threads + the network's)."""
        n = self.config.registration.polish_threads
        if n > 0:
            return n
        cores = threads_or_all(0)
        return max(1, cores - 1) if self.runner.working else cores

    def _cloud(
        self, points: Any, preprocessed: bool, name: str
    ) -> tuple[np.ndarray, np.ndarray | None, PreprocessResult | None]:
        """(sampled points (N, 3) float32, dense points (K, 3) float32 or None, the PreprocessResult (its
        precision-stage cloud, raw scan and times) or None) of one input."""
        if not isinstance(points, PreprocessResult):
            if preprocessed:
                return self._check(points, name), None, None
            points = as_xyz(points, name)  # the raw scan: errors name the source / target
            # the GICP cloud's k-d tree and covariances wait for the network process (_precision_clouds)
            points = self.preprocess(points, defer=self.defers_precision)
        dense = points.dense_points
        return self._check(points.points, name), None if dense is None else self._check(dense, name + " dense"), points

    @staticmethod
    def _check(points: np.ndarray, name: str) -> np.ndarray:
        """A preprocessed cloud: (N >= 3, 3), finite (core/points.py)."""
        return as_xyz(points, name, finite=True, min_points=3)

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
                pipeline runs from ``T_init`` on the clouds already built. Without ``T_init`` (or with
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
        clock.lap("preprocess")
        with torch.inference_mode(), self.network.torch_threads(), _answer_read(st):
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
        self._searched.append(st.starts > 1)
        result = self._result(st, clock)
        if good_start and T_init is not None:
            result.good_start = first.reason
        return result

    # -- the stages of register() ------------------------------------------------------------------
    def _start(self, source: Any, target: Any, T_init: np.ndarray | None, preprocessed: bool) -> _State:
        """Preprocess (raw scans only), the initial estimate, the scaled clouds on the device."""
        scale = self.model.scale
        tgt_np, tgt_dense, tgt_pre = self._cloud(target, preprocessed, "target")
        if not preprocessed and not isinstance(source, PreprocessResult) and self.network.n_deep:
            self.runner.send_target(tgt_np)  # the network process starts on the target while the source is prepared
        src_np, src_dense, src_pre = self._cloud(source, preprocessed, "source")
        T = np.eye(4) if T_init is None else as_transform(T_init)
        src, tgt = self.network.scaled(src_np), self.network.scaled(tgt_np)
        return _State(
            src_np=src_np, tgt_np=tgt_np, src_dense=src_dense, tgt_dense=tgt_dense, src_pre=src_pre, tgt_pre=tgt_pre,
            src_pc=None if src_pre is None else src_pre.polish_cloud,
            tgt_pc=None if tgt_pre is None else tgt_pre.polish_cloud,
            src=src, tgt=tgt, search=NeighbourSearch(tgt[0]),
            R=torch.as_tensor(T[:3, :3], dtype=torch.float32, device=self.device),
            t=torch.as_tensor(T[:3, 3] * scale, dtype=torch.float32, device=self.device),
            gamma=src.new_ones(src.shape[1]), T_start=T,
        )

    def _deep_passes(self, st: _State, clock: Clock) -> None:
        """DeepBBS: network passes on the moved source until the increment is small (or the cap); in the
        network process when there is one (``registration.network_process``: started here, read by
        :meth:`_network_result`)."""
        if not self.network.n_deep:
            return
        others = None
        if self.runner.process() is not None and st.yaw_search:
            others = global_search.speculative_starts(self.config.registration, st.T_start, self._searched)
            if others is not None:  # the network process's share; this process runs the rest once it is needed
                others = others[: worker_share(len(others))]
        st.pending = self.runner.submit(st.src_np, st.tgt_np, matrix(st.R, st.t, self.model.scale), others)
        if st.pending is not None:
            st.spec_n = 0 if others is None else len(others)
            return
        self._apply_network(st, self.network.passes(st.src, st.tgt, st.R, st.t, clock.lap))

    def _precision_clouds(self, st: _State, clock: Clock) -> None:
        """The k-d trees and covariances of raw scans' precision-stage clouds, deferred by :meth:`_start` (or by
        the node's inputs) while the network process runs (every core but the network's while it works)."""
        done = False
        for pc in (st.src_pc, st.tgt_pc):
            if pc is not None and pc.pending is not None:
                pc.complete(threads=self.gicp_threads())
                done = True
        if done:
            clock.lap("preprocess")

    def _network_result(self, st: _State, clock: Clock) -> None:
        """The network process's :class:`NetworkOutput` into the state; if it failed, the passes run here."""
        if st.pending is None:
            return
        pending, st.pending = st.pending, None
        out, away = self.runner.answer(pending, lambda: self.network.passes(st.src, st.tgt, st.R, st.t, clock.lap))
        if away:
            clock.lap("network_wait")
            st.network_ms = out.ms
            if pending.left:  # the worker goes on with the global search's other starts (speculatively)
                st.spec = pending
        self._apply_network(st, out)

    def _apply_network(self, st: _State, out: NetworkOutput) -> None:
        st.R = torch.as_tensor(out.R, dtype=torch.float32, device=self.device)
        st.t = torch.as_tensor(out.t, dtype=torch.float32, device=self.device)
        st.gamma = torch.as_tensor(out.gamma, dtype=torch.float32, device=self.device)
        st.temperature, st.iters["deep"], st.converged = out.temperature, out.iterations, out.converged

    @property
    def network_process_state(self) -> str:
        """"running (pid N)", "not started yet", "off" or "failed" (see ``registration.network_process``)."""
        return self.runner.describe()

    def close(self) -> None:
        """Stop the network process, if any (also done when this object is collected or at exit)."""
        self.runner.close()

    def _refine(self, st: _State) -> None:
        """DeepBBS++: SoftBBS on xyz over the k nearest targets, until the increment is tiny."""
        rc, scale = self.config.registration, self.model.scale
        if not rc.refine:
            return
        s_in, t_in, keep = st.src[0], st.tgt[0], None
        if rc.refine_overlap_crop:
            keep, t_keep = _overlap(s_in, t_in, st.R, st.t, self.config.preprocess.max_range * scale)
            if int(keep.sum()) >= 3 and int(t_keep.sum()) >= 3:
                s_in, t_in = s_in[keep], t_in[t_keep]
            else:
                keep = None
        t_ref = rc.refine_temperature * scale if rc.refine_temperature > 0 else 1.0
        ref = refine(
            s_in, t_in, st.R, st.t,
            k=rc.refine_k, max_iters=rc.refine_max_iters, rot_tol_deg=rc.refine_rot_tol_deg,
            trans_tol=rc.refine_trans_tol * scale, xi=self.model.cfg.xi, temperature=t_ref,
            use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma, search=st.search if keep is None else None,
            alpha_start=rc.refine_alpha_start,
        )  # fmt: skip
        st.R, st.t, st.gamma, st.converged, st.iters["refine"] = ref.R, ref.t, ref.gamma, ref.converged, ref.iterations
        if keep is not None:  # points outside the overlap get gamma 0
            st.gamma = st.src.new_zeros(st.src.shape[1]).masked_scatter_(keep, ref.gamma)

    def _dense_refine(self, st: _State) -> None:
        """The refinement on the voxelised non-ground clouds: a sharper alpha (their spacing is the voxel
        size, not the ~2 m of the sampled points) and a spatial T in metres."""
        rc, scale = self.config.registration, self.model.scale
        if not (rc.refine and rc.dense_refine and st.src_dense is not None and st.tgt_dense is not None):
            return
        d_src = torch.from_numpy(st.src_dense).to(self.device) * scale
        d_tgt = torch.from_numpy(st.tgt_dense).to(self.device) * scale
        if rc.refine_overlap_crop:
            ks, kt = _overlap(d_src, d_tgt, st.R, st.t, self.config.preprocess.max_range * scale)
            if int(ks.sum()) >= 3 and int(kt.sum()) >= 3:
                d_src, d_tgt = d_src[ks], d_tgt[kt]
        ref = refine(
            d_src, d_tgt, st.R, st.t,
            k=rc.dense_refine_k, max_iters=rc.dense_refine_max_iters, rot_tol_deg=rc.refine_rot_tol_deg,
            trans_tol=rc.refine_trans_tol * scale, xi=rc.dense_refine_xi,
            temperature=rc.dense_refine_temperature * scale,
            use_gamma=rc.use_gamma, spatial_gamma=rc.spatial_gamma,
        )  # fmt: skip
        st.R, st.t, st.converged, st.iters["dense"] = ref.R, ref.t, ref.converged, ref.iterations

    def _inlier_ratio(self, st: _State, R: torch.Tensor, t: torch.Tensor) -> float:
        """Share of the sampled source points within ``registration.inlier_dist`` of a target point."""
        moved = apply_transform(st.src, R[None], t[None])[0]
        return float((st.search.nearest_distance(moved) / self.model.scale <= self.config.registration.inlier_dist)
                     .float().mean())

    def _deskew(self, st: _State, clock: Clock) -> None:
        """Both scans deskewed with their own stream velocities (``core.deskew.StreamDeskew``): the precision
        stage again, from its result, on their ``deskewed_cloud`` s when each velocity agrees with the pair's mean
        motion (core/pair_deskew.py); ``st.deskew`` says what happened."""
        if st.src_pre is None or st.tgt_pre is None:
            return
        st.T, st.deskew, n = pair_deskew.again(st.src_pre, st.tgt_pre, st.T, self.config.registration,
                                               st.polish_reason == "ok")
        st.iters["polish"] += n
        if st.deskew == "deskewed":
            clock.lap("deskew")

    def _polish(self, st: _State, clock: Clock) -> None:
        """The precision stage: small_gicp GICP on the dense scans from the estimate (both clouds need
        their ``polish_cloud``; rejected results keep the estimate)."""
        rc = self.config.registration
        st.T = matrix(st.R, st.t, self.model.scale)
        if rc.polish == "none" or st.src_pc is None or st.tgt_pc is None:
            return
        pol = polish(st.src_pc, st.tgt_pc, st.T, rc, check=st.polish_check)
        st.iters["polish"], st.polish_reason = pol.iterations, pol.reason
        if pol.applied:
            st.T = pol.T_target_source
            st.T[:3, :3] = orthonormalize(st.T[:3, :3])
            with torch.inference_mode():
                Rp = torch.as_tensor(st.T[:3, :3], dtype=st.src.dtype, device=self.device)
                tp = torch.as_tensor(st.T[:3, 3] * self.model.scale, dtype=st.src.dtype, device=self.device)
                st.inlier_ratio = self._inlier_ratio(st, Rp, tp)
            st.converged = pol.converged
        clock.lap("polish")

    def _score(self, st: _State, T: np.ndarray, dist: float | None = None) -> float:
        """The verdict's score of the pose T (4, 4) (core/verdict.py) at ``dist`` m (``verdict_dist``): against
        the target's precision-stage cloud when it has one (calibrated), else against its voxelised non-ground
        points, else against its sampled points within ``max(dist, inlier_dist)``."""
        rc = self.config.registration
        d = rc.verdict_dist if dist is None else dist
        if st.tgt_pc is not None and st.tgt_pc.tree is not None and st.tgt_pc.pending is None:
            return verdict.fitness(st.src_np, st.tgt_pc.tree, T, d)
        if st.tgt_dense is not None and len(st.tgt_dense) >= len(st.tgt_np):  # no precision stage: voxelised
            return verdict.fitness_to_points(st.src_np, st.tgt_dense, T, d)
        return verdict.fitness_to_points(st.src_np, st.tgt_np, T, max(d, rc.inlier_dist))  # sparse: a wider gate

    def _verdict(self, st: _State) -> None:
        """The pose's score (fitness) and calibrated probability (core/verdict.py); valid from
        ``registration.verdict_probability``."""
        rc = self.config.registration
        st.score = self._score(st, st.T)
        if (st.tgt_pc is not None and st.tgt_pc.tree is not None and st.tgt_pc.pending is None
                and st.src_pc is not None):  # the good start's points and coefficients: they carry to real scans
            pts = good_start_points(st.src_pc, rc)
            st.probability = verdict.probability(pts, st.T, st.tgt_pc, rc.verdict_dist, "good_start")
            st.valid = verdict.is_valid(st.probability, rc.verdict_probability)
            return
        # no precision stage: the voxelised non-ground points, else the sampled ones, for which the probability is
        # not calibrated: reported, and the fitness decides (registration.verdict_threshold)
        dense = st.tgt_dense is not None and len(st.tgt_dense) >= len(st.tgt_np)
        st.probability = verdict.probability(st.src_np, st.T, st.tgt_dense if dense else st.tgt_np, rc.verdict_dist)
        st.valid = verdict.is_valid(st.score, rc.verdict_threshold)

    def _result(self, st: _State, clock: Clock) -> RegistrationResult:
        stages = ("preprocess", "embed", "match", "solve", "refine") + (("dense",) if st.iters["dense"] else ())
        stages += tuple(s for s in ("good_start", "network_wait", "polish", "deskew", "global") if s in clock.ms)
        timings = {s: clock.ms.get(s, 0.0) for s in stages}
        timings["total"] = sum(timings.values())  # the wall time of register(), less the start-up
        if "startup" in clock.ms:  # the network process's start (first call): its own figure, not in the total
            timings["startup"] = clock.ms["startup"]
        for s, v in st.network_ms.items():  # ran in the network process, overlapping "preprocess"
            timings[s] = v
        return RegistrationResult(
            T_target_source=st.T,
            converged=bool(st.converged),
            iterations=st.iters,
            gamma=st.gamma.float().cpu().numpy(),
            inlier_ratio=st.inlier_ratio,
            temperature=st.temperature,
            timings_ms=timings,
            source=st.src_np,
            target=st.tgt_np,
            polish=st.polish_reason,
            deskew=st.deskew,
            valid=bool(st.valid),
            score=float(st.score),
            probability=float(st.probability),
            starts=int(st.starts),
            path="search" if st.starts > 1 else "deepbbs",
        )


@dataclass
class _State:
    """What the stages of one ``register`` call share: the clouds (numpy, and scaled (1, N, 3) tensors on
    the device), the estimate R (3, 3), t (3,) in scaled units (T: the float64 metres matrix once the
    network stages are done), and the bookkeeping of the result."""

    src_np: np.ndarray
    tgt_np: np.ndarray
    src_dense: np.ndarray | None
    tgt_dense: np.ndarray | None
    src_pre: PreprocessResult | None
    tgt_pre: PreprocessResult | None
    src_pc: PolishCloud | None
    tgt_pc: PolishCloud | None
    src: torch.Tensor
    tgt: torch.Tensor
    search: NeighbourSearch
    R: torch.Tensor
    t: torch.Tensor
    gamma: torch.Tensor
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    iters: dict[str, int] = field(default_factory=lambda: {"deep": 0, "refine": 0, "dense": 0, "polish": 0})
    converged: bool = False
    temperature: float = 0.0
    inlier_ratio: float = 0.0
    polish_reason: str = ""
    deskew: str = ""
    T_start: np.ndarray = field(default_factory=lambda: np.eye(4))  # the given start (the global search turns it)
    score: float = float("nan")  # the verdict's fitness (core/verdict.py)
    probability: float = float("nan")  # the verdict: P(right)
    valid: bool = False
    starts: int = 1
    others: Any = None  # the global search's other starts, ranked: [(score, NetworkOutput, T)]
    replaced: Any = None  # (R, t, gamma) of the given start's answer when the search replaced it
    pending: Any = None  # a network_process.Pending while the network process works
    spec: Any = None  # the same, for its speculative passes from the global search's other starts
    spec_n: int = 0  # how many of those starts it was given (the first ones)
    yaw_search: bool = True  # register(yaw_search=False): the global search does not run for this call
    polish_check: tuple[int, float] | None = None  # register(polish_check=...): core.polish.polish's check
    network_ms: dict[str, float] = field(default_factory=dict)  # its embed / match / solve times


@contextlib.contextmanager
def _answer_read(st: _State) -> Iterator[None]:
    """An answer of the network process still pending when a stage raises is read and dropped: the worker
    takes one request at a time, and the next registration must not get this one's answer."""
    try:
        yield
    finally:
        pending, st.pending = st.pending, None
        NetworkRunner.discard(pending)  # read and dropped; speculative passes after it (if any) stopped
        spec, st.spec = st.spec, None
        NetworkRunner.drop(spec)


def _overlap(
    src: torch.Tensor, tgt: torch.Tensor, R: torch.Tensor, t: torch.Tensor, radius: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Masks of the points that both sensors could see: src (N, 3) and tgt (M, 3) (scaled) within
    ``radius`` of the other sensor under the estimate p_target = R p_source + t.

    Each scan was cropped at ``radius`` around its own sensor: a source point beyond ``radius`` of the
    target sensor has no partner in the target (and vice versa), and such unpaired ends of roads and
    walls pull a point-to-point refinement along the road. -> (src_mask (N,) bool, tgt_mask (M,) bool).
    """
    src_in_tgt = src @ R.T + t
    tgt_in_src = (tgt - t) @ R
    return src_in_tgt.norm(dim=1) <= radius, tgt_in_src.norm(dim=1) <= radius
