"""The inputs of ``DeepBBSRegistration`` (no ROS): raw scans preprocessed once (their precision-stage clouds, deskewed
copies), small_gicp's threads, and the start of one ``register`` call (its clouds checked, preprocessed when raw, the
initial estimate, the scaled clouds on the device: a :class:`~deepbbs_ros.core.registration_state.State`)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network import DeepBBSNetwork
from deepbbs_ros.core.network_runner import NetworkRunner
from deepbbs_ros.core.points import as_transform, as_xyz
from deepbbs_ros.core.polish import PolishCloud, threads_or_all
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.refine import NeighbourSearch
from deepbbs_ros.core.registration_state import State
from deepbbs_ros.core.scans import deskew_prepared, polish_cloud, prepare_scan

__all__ = ["RegistrationInputs"]


class RegistrationInputs:
    """Part of :class:`~deepbbs_ros.core.registration.DeepBBSRegistration`: its inputs."""

    # what it reads of the DeepBBSRegistration it is part of
    config: Config
    network: DeepBBSNetwork
    runner: NetworkRunner
    model: DeepBBSNet
    device: torch.device

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

    # -- the start of register() -------------------------------------------------------------------
    def _start(self, source: Any, target: Any, T_init: np.ndarray | None, preprocessed: bool) -> State:
        """Preprocess (raw scans only), the initial estimate, the scaled clouds on the device."""
        scale = self.model.scale
        tgt_np, tgt_dense, tgt_pre = self._cloud(target, preprocessed, "target")
        if not preprocessed and not isinstance(source, PreprocessResult) and self.network.n_deep:
            self.runner.send_target(tgt_np)  # the network process starts on the target while the source is prepared
        src_np, src_dense, src_pre = self._cloud(source, preprocessed, "source")
        T = np.eye(4) if T_init is None else as_transform(T_init)
        src, tgt = self.network.scaled(src_np), self.network.scaled(tgt_np)
        return State(
            src_np=src_np, tgt_np=tgt_np, src_dense=src_dense, tgt_dense=tgt_dense, src_pre=src_pre, tgt_pre=tgt_pre,
            src_pc=None if src_pre is None else src_pre.polish_cloud,
            tgt_pc=None if tgt_pre is None else tgt_pre.polish_cloud,
            src=src, tgt=tgt, search=NeighbourSearch(tgt[0]),
            R=torch.as_tensor(T[:3, :3], dtype=torch.float32, device=self.device),
            t=torch.as_tensor(T[:3, 3] * scale, dtype=torch.float32, device=self.device),
            gamma=src.new_ones(src.shape[1]), T_start=T,
        )
