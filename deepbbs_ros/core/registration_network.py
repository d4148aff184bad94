"""The deep passes of one ``DeepBBSRegistration.register`` call and their result (no ROS): sent to the network
process or run here (core/network.py, core/network_runner.py), the raw scans' precision-stage clouds built meanwhile,
the answer read into the :class:`~deepbbs_ros.core.registration_state.State`."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core import global_search
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.core.network import DeepBBSNetwork
from deepbbs_ros.core.network_output import Clock, NetworkOutput, matrix, worker_share
from deepbbs_ros.core.network_runner import NetworkRunner
from deepbbs_ros.core.registration_state import State

__all__ = ["NetworkStages"]


class NetworkStages:
    """Part of :class:`~deepbbs_ros.core.registration.DeepBBSRegistration`: the deep passes and their answer."""

    # what it reads of the DeepBBSRegistration it is part of
    config: Config
    network: DeepBBSNetwork
    runner: NetworkRunner
    model: DeepBBSNet
    device: torch.device
    _searched: deque[bool]
    gicp_threads: Callable[[], int]  # RegistrationInputs.gicp_threads

    def _deep_passes(self, st: State, clock: Clock) -> None:
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

    def _precision_clouds(self, st: State, clock: Clock) -> None:
        """The k-d trees and covariances of raw scans' precision-stage clouds, deferred by :meth:`_start` (or by
        the node's inputs) while the network process runs (every core but the network's while it works)."""
        done = False
        for pc in (st.src_pc, st.tgt_pc):
            if pc is not None and pc.pending is not None:
                pc.complete(threads=self.gicp_threads())
                done = True
        if done:
            clock.lap("preprocess")

    def _network_result(self, st: State, clock: Clock) -> None:
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

    def _apply_network(self, st: State, out: NetworkOutput) -> None:
        st.R = torch.as_tensor(out.R, dtype=torch.float32, device=self.device)
        st.t = torch.as_tensor(out.t, dtype=torch.float32, device=self.device)
        st.gamma = torch.as_tensor(out.gamma, dtype=torch.float32, device=self.device)
        st.temperature, st.iters["deep"], st.converged = out.temperature, out.iterations, out.converged
