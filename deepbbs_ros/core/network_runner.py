"""Where one registration's deep passes run: its network process, or this process (no ROS).

:class:`NetworkRunner` is the part of ``DeepBBSRegistration`` that decides it. On a CPU
(``registration.network_process``: auto) it starts the worker of core/network_process.py on first use and
hands it the passes, while the caller builds the GICP clouds; if the worker dies or stops answering, it logs
that once, stops it and the passes run in this process from then on (nothing is lost)::

    state      "unstarted" -> "running" on first use, or "off" (not wanted here) / "failed" (it died)
    submit     the passes of one request, in the worker (None: run them here)
    answer     a request's output, or the same passes run here when the worker failed
    starts     K starts (the global search's): the worker's share as one batch, the rest here as another
    speculated / drop   the outputs of the worker's speculative passes from other starts, or none

Clouds are (N, 3) float32 metres in the numpy calls and scaled (1, N, 3) tensors (``DeepBBSNetwork.scaled``)
in the in-process ones; outputs are :class:`~deepbbs_ros.core.network.NetworkOutput` s in scaled units.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable

import numpy as np
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.network import DeepBBSNetwork, NetworkOutput, worker_share
from deepbbs_ros.core.network_process import NetworkProcess, NetworkProcessLost, Pending
from deepbbs_ros.core.network_process import wanted as network_process_wanted
from deepbbs_ros.errors import ModelError, RegistrationError

__all__ = ["NetworkRunner"]

_log = logging.getLogger("deepbbs_ros.core.registration")  # its messages are the registration's


class NetworkRunner:
    """The deep passes of one network, in its worker process when there is one (thread-safe start-up).

    Args:
        network: the network (its checkpoint file is what the worker loads).
        config: the whole configuration (``registration.network_process``; sent to the worker).
    """

    def __init__(self, network: DeepBBSNetwork, config: Config) -> None:
        self.network, self.config = network, config
        self._net: NetworkProcess | None = None
        self._lock = threading.Lock()
        wants = network_process_wanted(config.registration.network_process, network.device.type,
                                       network.weights_path)
        self.state = "unstarted" if wants else "off"

    # -- the worker's life -----------------------------------------------------------------------------
    def process(self) -> NetworkProcess | None:
        """The worker (started on first use), or None (``registration.network_process`` "off", a GPU, one
        core, a model object instead of a checkpoint file, or a worker that failed)."""
        if self.state == "running" and self._net is not None and self._net.alive:
            return self._net
        if self.state != "unstarted":
            if self.state == "running":  # it died between two registrations
                self.failed(NetworkProcessLost("network process died"))
            return None
        with self._lock:
            if self.state == "unstarted":
                try:
                    self._net = NetworkProcess(self.network.weights_path, self.config.to_flat())
                    self.state = "running"
                except ModelError as err:
                    self.failed(err)
        return self._net if self.state == "running" else None

    def failed(self, err: Exception) -> None:
        """Log once, stop the worker and run the passes in this process from now on."""
        if self.state != "failed":
            _log.warning("%s: running the network in this process from now on", err)
        self.state = "failed"
        if self._net is not None:
            self._net.close()
            self._net = None

    @property
    def working(self) -> bool:
        """The worker is computing a request now (it holds a core)."""
        return self._net is not None and self._net.working

    @property
    def worker(self) -> NetworkProcess | None:
        """The running worker, if any (no start-up)."""
        return self._net

    def describe(self) -> str:
        """"running (pid N)", "not started yet", "off" or "failed"."""
        if self.state == "running" and self._net is not None:
            return f"running (pid {self._net.pid})"
        return {"unstarted": "not started yet"}.get(self.state, self.state)

    def close(self) -> None:
        """Stop the worker, if any (a later request starts a new one)."""
        if self._net is not None:
            self._net.close()
            self._net = None
        if self.state == "running":
            self.state = "unstarted"

    # -- requests --------------------------------------------------------------------------------------
    def send_target(self, tgt_np: np.ndarray) -> None:
        """Let the worker compute the network state of a preprocessed target (M, 3) now (best effort)."""
        net = self.process()
        if net is not None:
            net.prepare_target(tgt_np)

    def submit(self, src_np: np.ndarray, tgt_np: np.ndarray, T_start: np.ndarray,
               speculate: np.ndarray | None = None) -> Pending | None:
        """The deep passes from T_start (4, 4) metres in the worker (``speculate`` (K, 4, 4): its other starts
        after the answer, see ``NetworkProcess.submit``), or None: no worker, run them here."""
        net = self.process()
        if net is None:
            return None
        try:
            return net.submit(src_np, tgt_np, T_start, speculate=speculate)
        except NetworkProcessLost as err:
            self.failed(err)
            return None

    def answer(self, pending: Pending, here: Callable[[], NetworkOutput]) -> tuple[NetworkOutput, bool]:
        """(the worker's output for ``pending``, True), or (``here()``, False) when the worker failed or the
        passes raised there (run here, they raise the same error here)."""
        try:
            return pending.result(), True
        except NetworkProcessLost as err:
            self.failed(err)
        except RegistrationError:
            pass
        return here(), False

    def speculated(self, spec: Pending | None) -> list[NetworkOutput]:
        """The outputs of the worker's speculative passes (all, some, or none when there were none or the worker
        failed; waits for them)."""
        if spec is None:
            return []
        try:
            return list(spec.result())
        except NetworkProcessLost as err:
            self.failed(err)
        except RegistrationError:
            pass
        return []

    @staticmethod
    def drop(spec: Pending | None) -> None:
        """The speculative passes are not needed: the worker stops them (no wait)."""
        if spec is not None:
            spec.cancel()

    @staticmethod
    def discard(pending: Pending | None) -> None:
        """A request whose answer is no longer wanted (a stage raised): read and dropped, its speculative
        passes stopped, so that the next request does not get this one's answer."""
        if pending is None:
            return
        with contextlib.suppress(RegistrationError):
            pending.result()
        pending.cancel()

    def starts(self, src_np: np.ndarray, tgt_np: np.ndarray, src: torch.Tensor, tgt: torch.Tensor,
               starts: list[np.ndarray], n_passes: int, *, away: bool = True) -> list[NetworkOutput]:
        """``n_passes`` deep passes from each of ``starts`` ((4, 4) metres T_target_source guesses): the worker
        runs its share (``network.worker_share``, the first ones) as one batch while this process runs the others
        as another; with no worker (or ``away`` False) all here. -> the outputs in the order of the starts."""
        net = self.process() if starts and away else None
        pending, n_away = None, 0
        if net is not None and worker_share(len(starts)) > 0:
            n_away = worker_share(len(starts))
            try:
                pending = net.submit_starts(src_np, tgt_np, np.stack(starts[:n_away]), n_passes)
            except NetworkProcessLost as err:
                self.failed(err)
                n_away = 0
        try:
            here = self._starts_here(src, tgt, starts[n_away:], n_passes)
        except BaseException:
            if pending is not None:
                with contextlib.suppress(RegistrationError):
                    pending.result()  # read and dropped: the next request must not get this answer
            raise
        if pending is None:
            return here
        away_outs, _ = self.answer(pending, lambda: self._starts_here(src, tgt, starts[:n_away], n_passes))
        return away_outs + here

    def _starts_here(self, src: torch.Tensor, tgt: torch.Tensor, starts: list[np.ndarray],
                     n: int) -> list[NetworkOutput]:
        if not starts:
            return []
        T = np.stack(starts)
        R = torch.as_tensor(T[:, :3, :3], dtype=torch.float32, device=self.network.device)
        t = torch.as_tensor(T[:, :3, 3] * self.network.model.scale, dtype=torch.float32, device=self.network.device)
        return self.network.starts(src, tgt, R, t, n)
