"""The DeepBBS++ network passes in a worker process, so that they overlap with small_gicp on a CPU.

small_gicp's Python functions hold the GIL for their whole run (a covariance estimate of one HDL-64 scan
is ~18 ms), so a network in another *thread* of the same process stalls on every one of them. In a
worker process the network runs on its own core while the caller prepares the precision-stage clouds
(``DeepBBSRegistration.register`` on raw scans), or while the node's input threads preprocess the next
clouds. The messages are small: two (512, 3) float32 clouds in, a rotation, a translation and the
weights out (~0.3 ms per round trip). For the global search (core/global_search.py) a request can carry the
other start yaws: the worker runs them after its answer until a message stops it (``Pending.cancel``), and
answers K starts at once (``submit_starts``, one batch).

``registration.network_process``: "auto" (default) starts one per :class:`DeepBBSRegistration` on a CPU
device with 2+ cores and weights read from a checkpoint file (not for a model object handed in, such
as a training run's, whose weights change); "off" never does. The worker loads the same checkpoint
with the same configuration into the same :class:`~deepbbs_ros.core.network.DeepBBSNetwork` the
in-process path runs (this module imports the network only, never the registration), so its results
are the in-process ones. If it dies or does not answer in time, the caller logs it once and runs the network
itself from then on: nothing is lost. No ROS import.

Here: the caller's side; the worker's is :mod:`deepbbs_ros.core.network_worker`.
"""

from __future__ import annotations

import logging
import os
import threading
import weakref
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.core.network import NetworkOutput
from deepbbs_ros.core.worker_process import handshake, spawn_worker, stop_worker
from deepbbs_ros.errors import ModelError, RegistrationError

__all__ = ["NetworkOutput", "NetworkProcess", "NetworkProcessLost", "wanted"]

log = logging.getLogger(__name__)

START_TIMEOUT_S = 120.0  # importing torch and loading the checkpoint on a busy machine
RESULT_TIMEOUT_S = 60.0  # one registration's network passes (the first ones warm torch's kernels up)
STOP_GRACE_S = 2.0  # the worker's time to exit once asked to stop, before it is killed


class NetworkProcessLost(RegistrationError):
    """The worker died, stopped answering or could not be reached (it is stopped; a late answer must never
    be read as the next request's). Other worker errors are plain :class:`RegistrationError` s."""


def wanted(setting: str, device_type: str, weights_path: Path | None) -> bool:
    """Whether ``registration.network_process`` asks for a worker here ("auto": CPU, 2+ cores, weights
    from a file; "off": never)."""
    return setting == "auto" and device_type == "cpu" and weights_path is not None and (os.cpu_count() or 1) >= 2


class NetworkProcess:
    """One worker process running the network of a checkpoint; thread-safe (one request at a time).

    The worker is ``python -m deepbbs_ros.core.network_process`` on a socket pair, in its own session (a
    Ctrl-C in the terminal goes to the caller only; the worker ends when its socket closes), not a
    ``multiprocessing`` child: spawn would run the caller's ``__main__`` again, fork would copy torch's
    and DDS's threads.

    Args:
        weights: the checkpoint file.
        flat_config: ``Config.to_flat()`` of the caller (the worker forces ``network_process: off``).

    Raises:
        ModelError: the worker did not start (it could not load the checkpoint, or timed out).
    """

    def __init__(self, weights: str | Path, flat_config: dict[str, Any]) -> None:
        self._proc, self._conn = spawn_worker("deepbbs_ros.core.network_process", "network process")
        self._lock = threading.Lock()  # one request at a time: held from submit() until its answer is read
        self._send_lock = threading.Lock()  # one message at a time on the socket
        self._finalizer = weakref.finalize(self, stop_worker, self._conn, self._proc, STOP_GRACE_S)
        self._stale: Pending | None = None  # a cancelled request whose answer is still to be read
        try:
            handshake(self._conn, self._proc, (str(weights), flat_config), "network process", START_TIMEOUT_S)
        except ModelError:
            self.close()
            raise

    @property
    def alive(self) -> bool:
        return self._proc.poll() is None

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def working(self) -> bool:
        """A request is running in the worker (submitted, its answer not there yet): it uses a core (not counted
        once cancelled: it stops within a network stage)."""
        if not self._lock.locked() or self._stale is not None:
            return False
        try:
            return not self._conn.poll(0)
        except (OSError, ValueError):
            return False

    def submit(self, src: np.ndarray, tgt: np.ndarray, T_init: np.ndarray,
               speculate: np.ndarray | None = None) -> Pending:
        """Start the passes on src (N, 3), tgt (M, 3) float32 metres from T_init (4, 4); returns at once.
        The request holds the worker until :meth:`Pending.result` is read. ``speculate`` (K, 4, 4): once its
        answer is sent, the worker goes on with one pass from each of these starts (the global search's other
        start yaws) until they are done or another message comes (:meth:`Pending.cancel`); the second
        :meth:`Pending.result` is then the list of the :class:`NetworkOutput` s done, in order (maybe fewer)."""
        msg = ("run", np.ascontiguousarray(src, np.float32), np.ascontiguousarray(tgt, np.float32),
               np.asarray(T_init, np.float64))
        if speculate is None or len(speculate) == 0:
            return self._request(msg)
        return self._request((*msg, np.asarray(speculate, np.float64).reshape(-1, 4, 4)), answers=2)

    def _drain(self) -> None:
        """Read and drop the answer of a cancelled request (it holds the worker until read)."""
        stale, self._stale = self._stale, None
        while stale is not None and stale.left:
            try:
                stale.result()
            except RegistrationError:
                break

    def _request(self, msg: tuple, answers: int = 1) -> Pending:
        self._drain()
        if not self._lock.acquire(timeout=RESULT_TIMEOUT_S):  # another request's answer was never read
            raise NetworkProcessLost(f"network process: still busy after {RESULT_TIMEOUT_S:.0f} s")
        try:
            with self._send_lock:
                self._conn.send(msg)
        except (OSError, ValueError) as err:
            self._lock.release()
            self.close()
            raise NetworkProcessLost(f"network process: request failed ({err})") from err
        return Pending(self, answers)

    def submit_starts(self, src: np.ndarray, tgt: np.ndarray, T_starts: np.ndarray, n_passes: int) -> Pending:
        """Start ``n_passes`` deep passes from each of K starts T_starts (K, 4, 4) as one batch
        (``DeepBBSNetwork.starts_np``); :meth:`Pending.result` is then a list of K :class:`NetworkOutput` s."""
        return self._request(("starts", np.ascontiguousarray(src, np.float32), np.ascontiguousarray(tgt, np.float32),
                              np.asarray(T_starts, np.float64).reshape(-1, 4, 4), int(n_passes)))

    def prepare_target(self, tgt: np.ndarray) -> None:
        """Let the worker compute the network state of target (M, 3) float32 metres now (no answer): the next
        request with the same target finds it ready (``DeepBBSNetwork.target_state``). Best effort."""
        try:
            with self._send_lock:
                self._conn.send(("target", np.ascontiguousarray(tgt, np.float32)))
        except (OSError, ValueError):
            pass  # the next submit() finds out

    def close(self) -> None:
        """Stop the worker (also done when this object is collected and at interpreter exit)."""
        self._finalizer()


class Pending:
    """Answers on their way from :class:`NetworkProcess`; :meth:`result` once per answer (two for a request
    with ``speculate``); the worker is held until the last is read."""

    def __init__(self, owner: NetworkProcess, answers: int = 1) -> None:
        self._owner = owner
        self.left = answers  # answers still to be read

    def ready(self) -> bool:
        """The answer is there (or the worker is gone): :meth:`result` will not wait."""
        try:
            return not self.left or self._owner._conn.poll(0)
        except (OSError, ValueError):
            return True

    def cancel(self) -> None:
        """The answers left are not wanted: the worker stops its speculative passes (any message ends them), and
        the answer is read and dropped before the next request (no wait here)."""
        if not self.left:
            return
        owner = self._owner
        try:
            with owner._send_lock:
                owner._conn.send(("cancel",))
        except (OSError, ValueError):
            pass  # the next request finds out
        owner._stale = self

    def result(self, timeout: float = RESULT_TIMEOUT_S) -> Any:
        """The worker's :class:`NetworkOutput` (a list of them for :meth:`NetworkProcess.submit_starts`).

        Raises:
            NetworkProcessLost: the worker died or timed out (it is then stopped).
            RegistrationError: the passes raised in the worker (it keeps running).
        """
        if not self.left:
            raise RegistrationError("network process: result already read")
        owner = self._owner
        msg = ("error", "no answer")
        try:
            if not owner._conn.poll(timeout):
                owner.close()
                raise NetworkProcessLost(f"network process: no answer within {timeout:.0f} s")
            msg = owner._conn.recv()
        except (EOFError, OSError) as err:
            owner.close()
            raise NetworkProcessLost(f"network process died (exit code {owner._proc.poll()})") from err
        finally:
            self.left = self.left - 1 if msg[0] == "ok" else 0  # an error ends the request
            if not self.left:
                owner._lock.release()
                if owner._stale is self:
                    owner._stale = None
        if msg[0] != "ok":
            raise RegistrationError(f"network process: {msg[1]}")
        return msg[1]


if __name__ == "__main__":  # the worker (network_worker.py), started under this module's name
    import sys

    from deepbbs_ros.core.network_worker import _worker_main

    sys.exit(_worker_main(int(sys.argv[1])))
