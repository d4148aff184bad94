"""The pair-mode node's registration in a process of its own (no ROS import).

On a CPU everything GIL-bound of the pair-mode node used to run in the node's one process: rclpy's receive,
the PointCloud2 decoding, each new cloud's preprocessing (small_gicp's voxel grid, ground, FPS), the GICP
cloud's k-d tree and covariances and GICP itself; small_gicp holds the GIL for the whole of each call, so
these queue behind each other on one core while the second core is only partly used by the network
process. With ``node.registration_process`` (auto, the default: on in pair mode on a CPU with 2+ cores, for the
node's own DeepBBS++) the node's process keeps rclpy, decoding and each new cloud's preprocessing, and this
module's worker process owns the :class:`~deepbbs_ros.core.registration.DeepBBSRegistration` (which keeps its
own network process): the GICP clouds' k-d trees and covariances, GICP and the verdict. Node process +
registration process + network process. (Preprocessing in the worker as well left it with 85-115 ms of
GIL-bound work per 100 ms period on real HDL-64E scans: measured, it answered fewer pairs.)

::

    node process                                 registration process (python -m deepbbs_ros.node.registration_process)
    input thread k: preprocess (deferred GICP cloud)
                   ── adopt(result) ──────────▶ lane "input k": kept under a handle → ScanHandle
                   ── deskew(handle) ─────────▶  the same lane: that topic's StreamDeskew (node.pair_deskew)
    registration   ── register(src, tgt) ─────▶ lane "registration": DeepBBSRegistration.register → result
    handle freed   ── release (with the next request)  (the scan is forgotten there)

Requests carry the node thread's name: each node thread has a thread of its own in the worker (its
"lane"), so the worker overlaps preprocessing with a registration's network wait exactly as the node's
threads did. A scan preprocessed there stays there under a handle (:class:`ScanHandle`, the node's
``Cloud.pp``): the node's content-keyed cache hands the same handle out again (a target reused as the
next source, a fixed target), and a handle the node drops is released with the next request; the worker
also keeps at most :data:`MAX_SCANS` (the oldest forgotten). What comes back is small: the sampled points
(512 x 3, for the node's covariances), the timings, and the pickled ``RegistrationResult``.

The worker is started like the network process (``core/network_process.py``: a subprocess on a socket
pair, in its own session, the same checkpoint and config). A RegistrationError there (bad input) comes
back as a RegistrationError with its one-line message. If the worker dies or stops answering, the proxy
logs one line and runs every request in the node's process from then on (nothing is lost but time). A
``PolishCloud`` pickles as its voxel grid, its k-d tree and covariances deferred (core/polish_cloud.py).

Here: the proxy the node calls. Its fallback in the node's process is :mod:`deepbbs_ros.node.registration_fallback`,
the worker's side :mod:`deepbbs_ros.node.registration_worker`, the connection between them (requests, answers,
releases) :mod:`deepbbs_ros.node.registration_link`, the node's handle of a scan :mod:`deepbbs_ros.node.scan_handle`.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.core.scans import prepare_scan
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.registration_fallback import LocalFallback
from deepbbs_ros.node.registration_link import RESULT_TIMEOUT_S, WorkerLink, _Lost  # noqa: F401 - RESULT_TIMEOUT_S
from deepbbs_ros.node.registration_worker import MAX_SCANS, _Expired  # noqa: F401 - MAX_SCANS: imported from here
from deepbbs_ros.node.scan_handle import ScanHandle, _RemoteStreamDeskew

__all__ = ["RegistrationProcess", "ScanHandle", "wanted"]

_log = logging.getLogger(__name__)

START_TIMEOUT_S = 180.0  # importing torch, loading the checkpoint, starting the network process, warming up


def wanted(setting: str, mode: str, device_type: str) -> bool:
    """Whether ``node.registration_process`` asks for the worker: "on" in pair mode, "auto" in pair mode on a
    CPU with 2+ cores, "off" never (odometry mode keeps its registration in the node's process)."""
    if mode != "pair" or setting == "off":
        return False
    return setting == "on" or (device_type == "cpu" and (os.cpu_count() or 1) >= 2)


class RegistrationProcess(LocalFallback):
    """The node's DeepBBS++ registration in a worker process, behind the interface the node uses:
    ``preprocess(xyz, times, stamp_ns, *, defer)`` -> :class:`ScanHandle`, ``register(src, tgt, *, T_init)`` ->
    ``RegistrationResult``, ``stream_deskew()`` (a ``StreamDeskew`` per input topic), ``close()``.

    Args:
        config: the registration's config (the node's ``node_registration_config``).
        weights: the checkpoint file.
        log: called with the one line said when the worker is lost (default: this module's logger).

    Raises:
        ModelError: the worker did not start (it could not load the checkpoint, or timed out).
    """

    defers_precision = True  # the worker decides (its own DeepBBSRegistration.defers_precision)

    def __init__(self, config: Any, weights: str | Path, log: Callable[[str], None] | None = None) -> None:
        self.config, self.weights = config, str(weights)
        self.device = "cpu"  # the worker's, once it is ready
        self._log = log or _log.warning
        self._local: Any = None  # the DeepBBSRegistration of the fallback
        self._local_lock = threading.Lock()
        self._state = "starting"
        self._net_state = "not started yet"  # the worker's network process, as it last said
        self._link = WorkerLink("deepbbs_ros.node.registration_process", "registration process",
                                (self.weights, config.to_flat()), START_TIMEOUT_S)  # ModelError: it is stopped
        self._proc, self._ids, self._released = self._link.proc, self._link.ids, self._link.released
        self._call = self._link.call
        self._net_state, self.device = self._link.hello[1], self._link.hello[2]
        self._state = "running"
        self._link.start_reader()

    # -- state ---------------------------------------------------------------------------------------
    @property
    def alive(self) -> bool:
        return self._state == "running" and self._proc.poll() is None

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def state(self) -> str:
        """"running (pid N)", "failed (in the node's process)" or "stopped"."""
        if self._state == "running":
            return f"running (pid {self._proc.pid})"
        return {"failed": "failed (registering in the node's process)"}.get(self._state, self._state)

    @property
    def network_process_state(self) -> str:
        """The network process of the registration (the worker's, as it last said; the fallback's)."""
        if self._local is not None:
            return self._local.network_process_state
        return self._net_state if self._state == "running" else "stopped (with the registration process)"

    @property
    def handles(self) -> int:
        """Requests waiting for their answer (0 when idle)."""
        return self._link.waiting

    # -- the interface the node uses ----------------------------------------------------------------
    def preprocess(self, points: np.ndarray, times: np.ndarray | None = None, stamp_ns: int | None = None,
                   motion: tuple[np.ndarray, float] | None = None, *, defer: bool = False,
                   lazy: bool = False, driver: str | None = None) -> ScanHandle:
        """``DeepBBSRegistration.preprocess`` (``core.scans.prepare_scan``, ``driver`` as there) in this thread, the
        result handed to the worker (which builds its GICP cloud's k-d tree and covariances when it registers it) -> a
        :class:`ScanHandle` of it. ``lazy``: the sampled points wait for their first use, in the worker (a good start
        never needs them); the handle's ``points`` are then None.

        Raises:
            RegistrationError: bad input, with its one-line message.
        """
        if self._state == "running":
            hid = next(self._ids)
            try:
                xyz = np.ascontiguousarray(points)
                tt = None if times is None else np.ascontiguousarray(times)
                stamp = None if stamp_ns is None else int(stamp_ns)
                h = self._handle(hid, xyz, tt, stamp, self._adopt(hid, xyz, tt, stamp, motion, lazy, driver))
                h.driver = driver
                return h
            except _Lost as err:
                self._failed(err)
        return self._local_preprocess(points, times, stamp_ns, motion, defer, lazy, driver)

    def register(self, source: Any, target: Any, *, T_init: np.ndarray | None = None,
                 preprocessed: bool = False, good_start: bool = False) -> Any:
        """``DeepBBSRegistration.register`` of two handles (or raw scans, preprocessed first) in the worker; the
        result's ``timings_ms`` gain ``transfer``: the request's time beyond the worker's own.

        Raises:
            RegistrationError: the worker's, with its message.
        """
        if preprocessed:
            raise RegistrationError("registration process: preprocessed arrays are not supported; pass the scans")
        src = source if isinstance(source, ScanHandle) else self.preprocess(source)
        tgt = target if isinstance(target, ScanHandle) else self.preprocess(target)
        T = None if T_init is None else np.asarray(T_init, np.float64)
        for _ in range(3):  # a scan the worker forgot (the node held more than MAX_SCANS) is sent again
            if not (self._state == "running" and src.local is None and tgt.local is None):
                break
            t0 = time.perf_counter()
            try:
                result, net_state, wall_ms = self._call(("register", src.id, tgt.id, T, good_start))
                self._net_state = net_state
                result.timings_ms["transfer"] = max(0.0, (time.perf_counter() - t0) * 1e3 - wall_ms)
                return result
            except _Expired as err:
                self._again(src if int(str(err)) == src.id else tgt)
            except _Lost as err:
                self._failed(err)
        local = self._fallback()
        return local.register(self._localized(src), self._localized(tgt), T_init=T, good_start=good_start)

    def kept(self) -> int:
        """Scans the worker keeps now (after the releases sent with this request); 0 without a worker."""
        if self._state != "running":
            return 0
        try:
            return int(self._call(("kept",)))
        except _Lost as err:
            self._failed(err)
            return 0

    def stream_deskew(self) -> _RemoteStreamDeskew:
        """A ``StreamDeskew`` for one input topic, run in the worker (its ``apply(handle)`` -> a new handle)."""
        return _RemoteStreamDeskew(self, f"stream-{next(self._ids)}")

    def warmup(self) -> None:
        """Nothing to do here: the worker warms its registration up before it answers ``ready``."""

    def close(self) -> None:
        """Stop the worker (also done when this object is collected and at interpreter exit) and the fallback's
        network process."""
        if self._state == "running":
            self._state = "stopped"
        self._link.stop()
        with self._local_lock:
            if self._local is not None:
                self._local.close()

    # -- internals -------------------------------------------------------------------------------------
    def _handle(self, hid: int, xyz: np.ndarray, times: Any, stamp: Any, out: dict) -> ScanHandle:
        h = ScanHandle(hid, xyz, times, stamp, out["points"], out["timings_ms"], out["deskew"])
        h.sensor = out.get("sensor", "auto")
        weakref.finalize(h, self._released.append, hid)  # appended only: safe from any thread, even inside GC
        return h

    def _deskew(self, stream: _RemoteStreamDeskew, pre: ScanHandle) -> ScanHandle:
        if self._state == "running" and pre.local is None:
            hid = next(self._ids)
            try:
                out = self._call(("deskew", stream.key, pre.id, hid))
                h = self._handle(hid, pre.xyz, pre.times, pre.stamp_ns, out)
                h.driver = pre.driver
                return h
            except _Lost as err:
                self._failed(err)
        return self._local_deskew(stream, pre)

    def _adopt(self, hid: int, xyz: np.ndarray, times: Any, stamp: Any, motion: Any, lazy: bool = False,
               driver: str | None = None) -> dict:
        """Preprocess a scan here (numpy, mostly without the GIL) and hand it to the worker under ``hid`` (the GICP
        cloud's k-d tree and covariances are built there; with ``lazy`` the sampling too, when first needed) -> the
        worker's reply."""
        pre = prepare_scan(self.config, xyz, times, stamp, motion, defer=True, threads=0, lazy=lazy, driver=driver)
        return self._call(("adopt", hid, pre))

    def _again(self, h: ScanHandle) -> None:
        """Preprocess a handle's scan again for the worker, under a new id (its deskew is not redone)."""
        hid = next(self._ids)
        try:
            self._adopt(hid, h.xyz, h.times, h.stamp_ns, None, driver=h.driver)
        except _Lost as err:
            self._failed(err)
            return
        h.id = hid
        weakref.finalize(h, self._released.append, hid)  # (the old id's finalizer releases a forgotten scan)

    def _send_quiet(self, msg: tuple) -> None:
        if self._state == "running":
            self._link.send_quiet(msg)  # a failure: the next request finds out


if __name__ == "__main__":  # the worker (registration_worker.py), started under this module's name
    import sys

    from deepbbs_ros.node.registration_worker import _worker_main

    sys.exit(_worker_main(int(sys.argv[1])))
