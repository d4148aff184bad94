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
logs one line, loads the registration in the node's process, and runs every request there from then on
(a handle of the dead worker is preprocessed again from its points: nothing is lost but time). A
``PolishCloud`` pickles as its voxel grid, its k-d tree and covariances deferred (core/polish.py).
"""

from __future__ import annotations

import itertools
import logging
import os
import threading
import time
import weakref
from collections import OrderedDict, deque
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.core.scans import prepare_scan
from deepbbs_ros.errors import DeepBBSError, ModelError, RegistrationError

__all__ = ["RegistrationProcess", "ScanHandle", "wanted"]

_log = logging.getLogger(__name__)

START_TIMEOUT_S = 180.0  # importing torch, loading the checkpoint, starting the network process, warming up
RESULT_TIMEOUT_S = 60.0  # one request (a registration with its global search on a busy machine)
MAX_SCANS = 16  # scans kept by the worker (the node releases the ones it drops; this bounds a leak)


def wanted(setting: str, mode: str, device_type: str) -> bool:
    """Whether ``node.registration_process`` asks for the worker: "on" in pair mode, "auto" in pair mode on a
    CPU with 2+ cores, "off" never (odometry mode keeps its registration in the node's process)."""
    if mode != "pair" or setting == "off":
        return False
    return setting == "on" or (device_type == "cpu" and (os.cpu_count() or 1) >= 2)


class ScanHandle:
    """A scan preprocessed in the registration process (what the node keeps as ``Cloud.pp``).

    Attributes:
        points: (M, 3) float32 sampled points (``PreprocessResult.points``), None while their sampling waits
            (``preprocess(..., lazy=True)``).
        timings_ms: the worker's preprocessing timings.
        deskew: the worker's ``PreprocessResult.deskew``.
        local: the ``PreprocessResult`` in the node's process, once the proxy runs there (fallback).
        driver: the driver that published the scan (``preprocess(..., driver=)``), for a scan preprocessed again.
        sensor: the sensor whose defaults it was preprocessed with (``PreprocessResult.sensor``).
    """

    __slots__ = ("id", "xyz", "times", "stamp_ns", "points", "timings_ms", "deskew", "local", "driver",
                 "sensor", "__weakref__")

    def __init__(self, hid: int, xyz: np.ndarray, times: np.ndarray | None, stamp_ns: int | None,
                 points: np.ndarray | None = None, timings_ms: dict | None = None, deskew: str = "",
                 local: Any = None) -> None:
        self.id, self.xyz, self.times, self.stamp_ns = hid, xyz, times, stamp_ns
        self.points = points if local is None else (local.points if getattr(local, "sampled", True) else None)
        self.timings_ms = dict(timings_ms or (local.timings_ms if local is not None else {}))
        self.deskew = deskew if local is None else local.deskew
        self.local = local
        self.driver: str | None = None
        self.sensor: str = getattr(local, "sensor", "auto")

    def __repr__(self) -> str:
        where = "local" if self.local is not None else f"remote #{self.id}"
        return f"ScanHandle({where}, {len(self.xyz)} points, stamp {self.stamp_ns})"


class _Lost(RegistrationError):
    """The worker died, stopped answering or could not be reached."""


class _Expired(RegistrationError):
    """A scan the worker no longer keeps (more than :data:`MAX_SCANS` held by the node)."""


class _RemoteStreamDeskew:
    """``core.deskew.StreamDeskew`` of one input topic, run in the worker (``apply`` / ``reset``)."""

    def __init__(self, owner: RegistrationProcess, key: str) -> None:
        self._owner, self.key = owner, key
        self._local: Any = None  # the fallback's StreamDeskew

    def apply(self, pre: ScanHandle) -> ScanHandle:
        return self._owner._deskew(self, pre)

    def reset(self) -> None:
        if self._local is not None:
            self._local.reset()
        self._owner._send_quiet(("reset_stream", self.key))


class RegistrationProcess:
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
        from deepbbs_ros.core.worker_process import handshake, spawn_worker

        self.config, self.weights = config, str(weights)
        self.device = "cpu"  # the worker's, once it is ready
        self._log = log or _log.warning
        self._ids = itertools.count(1)
        self._futures: dict[int, Future] = {}
        self._futures_lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._released: deque[int] = deque()  # handles dropped by the node, sent with the next request
        self._local: Any = None  # the DeepBBSRegistration of the fallback
        self._local_lock = threading.Lock()
        self._state = "starting"
        self._net_state = "not started yet"  # the worker's network process, as it last said
        self._proc, self._conn = spawn_worker("deepbbs_ros.node.registration_process", "registration process")
        self._finalizer = weakref.finalize(self, _shutdown, self._conn, self._proc)
        try:
            msg = handshake(self._conn, self._proc, (self.weights, config.to_flat()), "registration process",
                            START_TIMEOUT_S)
        except ModelError:
            self.close()
            raise
        self._net_state, self.device = msg[1], msg[2]
        self._state = "running"
        self._reader = threading.Thread(target=self._read, name="deepbbs-regproc-reader", daemon=True)
        self._reader.start()

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
        with self._futures_lock:
            return len(self._futures)

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
        local = self._fallback()
        h = ScanHandle(0, points, times, stamp_ns, local=local.preprocess(points, times, stamp_ns, motion,
                                                                          defer=defer and local.defers_precision,
                                                                          lazy=lazy, driver=driver))
        h.driver = driver
        return h

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
        self._finalizer()
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
        local = self._fallback()
        if stream._local is None:
            from deepbbs_ros.core.deskew import StreamDeskew

            stream._local = StreamDeskew(local)
        h = ScanHandle(0, pre.xyz, pre.times, pre.stamp_ns, local=stream._local.apply(self._localized(pre)))
        h.driver = pre.driver
        return h

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

    def _localized(self, h: ScanHandle) -> Any:
        """The handle's PreprocessResult in this process (preprocessed again once, after a fallback)."""
        if h.local is None:
            local = self._fallback()
            h.local = local.preprocess(h.xyz, h.times, h.stamp_ns, defer=local.defers_precision, lazy=True,
                                       driver=h.driver)
        return h.local

    def _call(self, msg: tuple) -> Any:
        """Send one request from this thread's lane and wait for its answer.

        Raises:
            _Lost: the worker is gone or did not answer in time (it is then stopped).
            RegistrationError: the worker raised one (its message).
        """
        rid = next(self._ids)
        fut: Future = Future()
        with self._futures_lock:
            self._futures[rid] = fut
        released = []
        while self._released:
            released.append(self._released.popleft())
        lane = threading.current_thread().name
        try:
            with self._send_lock:
                if released:
                    self._conn.send(("release", released))
                self._conn.send((rid, lane, msg))
        except (OSError, ValueError) as err:
            with self._futures_lock:
                self._futures.pop(rid, None)
            code = self._proc.poll()
            raise _Lost(f"registration process died (exit code {code})" if code is not None
                        else f"registration process: request failed ({err})") from err
        try:
            status, value = fut.result(timeout=RESULT_TIMEOUT_S)
        except TimeoutError as err:
            with self._futures_lock:
                self._futures.pop(rid, None)
            raise _Lost(f"registration process: no answer within {RESULT_TIMEOUT_S:.0f} s") from err
        if status == "ok":
            return value
        if status == "lost":
            raise _Lost(value)
        if status == "expired":
            raise _Expired(value)
        if status == "registration_error":
            raise RegistrationError(value)
        raise DeepBBSError(f"registration process: {value}")  # a bug there: the node logs it and goes on

    def _send_quiet(self, msg: tuple) -> None:
        if self._state != "running":
            return
        try:
            with self._send_lock:
                self._conn.send(msg)
        except (OSError, ValueError):
            pass  # the next request finds out

    def _read(self) -> None:
        """The answers, to the waiting requests; the worker's end to every request still waiting."""
        why = "registration process: connection closed"
        while True:
            try:
                rid, status, value = self._conn.recv()
            except (EOFError, OSError, ValueError):
                code = self._proc.poll()
                why = f"registration process died (exit code {code})" if code is not None else why
                break
            with self._futures_lock:
                fut = self._futures.pop(rid, None)
            if fut is not None:
                fut.set_result((status, value))
        with self._futures_lock:
            waiting, self._futures = list(self._futures.values()), {}
        for fut in waiting:
            fut.set_result(("lost", why))

    def _failed(self, err: Exception) -> None:
        """Log once, stop the worker and register in this process from now on."""
        with self._local_lock:
            if self._state == "failed":
                return
            stopping = self._state == "stopped"
            self._state = "failed"
        if not stopping:
            self._log(f"{err}: registering in the node's process from now on")
        self._finalizer()

    def _fallback(self) -> Any:
        """The DeepBBSRegistration of this process (built once, on the first request after a failure)."""
        if self._state == "running":
            raise RegistrationError("registration process: internal error (fallback while running)")
        with self._local_lock:
            if self._local is None:
                if self._state == "stopped":
                    raise RegistrationError("registration process: closed")
                from deepbbs_ros.core.registration import DeepBBSRegistration

                self._local = DeepBBSRegistration(self.config, weights=self.weights)
                self._local.warmup()
            return self._local


def _shutdown(conn, proc) -> None:
    try:
        conn.send(("stop",))
    except (OSError, ValueError):
        pass
    try:
        proc.wait(timeout=5.0)
    except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired
        proc.kill()
        proc.wait(timeout=2.0)
    conn.close()


# -- the worker ----------------------------------------------------------------------------------------
class _Worker:
    """The registration and the scans it keeps, served on one thread per lane (the node's threads)."""

    def __init__(self, conn: Any, reg: Any) -> None:
        self.conn, self.reg = conn, reg
        self.send_lock = threading.Lock()
        self.scans: OrderedDict[int, Any] = OrderedDict()
        self.scans_lock = threading.Lock()
        self.streams: dict[str, Any] = {}
        self.lanes: dict[str, deque] = {}
        self.cond = threading.Condition()
        self.stopping = False

    def put(self, hid: int, pre: Any) -> None:
        with self.scans_lock:
            self.scans[hid] = pre
            while len(self.scans) > MAX_SCANS:
                self.scans.popitem(last=False)

    def get(self, hid: int) -> Any:
        with self.scans_lock:
            pre = self.scans.get(hid)
            if pre is not None:
                self.scans.move_to_end(hid)
        if pre is None:
            raise _Expired(str(hid))
        return pre

    def release(self, ids: list[int]) -> None:
        with self.scans_lock:
            for hid in ids:
                self.scans.pop(hid, None)

    def submit(self, rid: int, lane: str, msg: tuple) -> None:
        with self.cond:
            q = self.lanes.get(lane)
            if q is None:
                q = self.lanes[lane] = deque()
                threading.Thread(target=self._serve, args=(q, lane), name=f"lane-{lane}", daemon=True).start()
            q.append((rid, msg))
            self.cond.notify_all()

    def stop(self) -> None:
        with self.cond:
            self.stopping = True
            self.cond.notify_all()

    def _serve(self, q: deque, lane: str) -> None:
        from deepbbs_ros.node.worker import _name_os_thread

        _name_os_thread(lane.removeprefix("deepbbs-"))  # as the node's thread is named (top -H, the benchmark)
        while True:
            with self.cond:
                self.cond.wait_for(lambda: q or self.stopping)
                if self.stopping:
                    return
                rid, msg = q.popleft()
            try:
                answer = (rid, "ok", self.run(msg))
            except _Expired as err:
                answer = (rid, "expired", str(err))
            except RegistrationError as err:
                answer = (rid, "registration_error", str(err))
            except Exception as err:  # noqa: BLE001 - a bug: one line to the node, which goes on
                answer = (rid, "error", f"{type(err).__name__}: {err}")
            try:
                with self.send_lock:
                    self.conn.send(answer)
            except (OSError, ValueError):
                return

    @staticmethod
    def _reply(pre: Any) -> dict:  # a waiting sampling stays waiting (PreprocessResult.sample): no points yet
        points = pre.points if getattr(pre, "sampled", True) else None
        return {"points": points, "timings_ms": dict(pre.timings_ms), "deskew": pre.deskew,
                "sensor": getattr(pre, "sensor", "auto")}

    def run(self, msg: tuple) -> Any:
        op = msg[0]
        if op == "adopt":  # a scan the node preprocessed: its GICP cloud's k-d tree and covariances are built here
            _, hid, pre = msg
            if self.reg.config.node.good_start and pre.polish_cloud is not None:
                # pairs from a good start run GICP alone (no network to overlap the k-d tree and covariances with, in
                # register): built now, on this input's lane, while the registration lane works on the last pair
                t0 = time.perf_counter()
                pre.polish_cloud.complete(self.reg.gicp_threads())
                pre.timings_ms["polish_prepare"] = pre.timings_ms.get("polish_prepare", 0.0) + (
                    time.perf_counter() - t0) * 1e3
            self.put(hid, pre)
            return self._reply(pre)
        if op == "deskew":
            _, key, hid, new_id = msg
            stream = self.streams.get(key)
            if stream is None:
                from deepbbs_ros.core.deskew import StreamDeskew

                stream = self.streams[key] = StreamDeskew(self.reg)
            pre = stream.apply(self.get(hid))
            self.put(new_id, pre)
            return self._reply(pre)
        if op == "register":
            _, src_id, tgt_id, T_init, good_start = msg
            t0 = time.perf_counter()
            result = self.reg.register(self.get(src_id), self.get(tgt_id), T_init=T_init, good_start=good_start)
            return result, self.reg.network_process_state, (time.perf_counter() - t0) * 1e3
        if op == "kept":
            with self.scans_lock:
                return len(self.scans)
        raise ValueError(f"unknown request {op!r}")


def _worker_main(fd: int) -> int:
    """Read (weights, flat config), build and warm up the registration, answer ``("ready", network process
    state, device)``, then serve ``(request id, lane, request)`` messages (and ``("release", ids)``,
    ``("reset_stream", key)``) until ``("stop",)`` or until the node is gone (EOF)."""
    from multiprocessing.connection import Connection

    conn = Connection(fd)
    try:
        weights, flat_config = conn.recv()
        from deepbbs_ros.config import Config
        from deepbbs_ros.core.registration import DeepBBSRegistration

        reg = DeepBBSRegistration(Config.from_flat(flat_config), weights=weights)
        reg.warmup()
    except (EOFError, OSError):
        return 0
    except Exception as err:  # noqa: BLE001 - reported to the caller as one line
        conn.send(("error", f"{type(err).__name__}: {err}"))
        return 1
    conn.send(("ready", reg.network_process_state, str(reg.device)))
    worker = _Worker(conn, reg)
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "stop":
                break
            if msg[0] == "release":
                worker.release(msg[1])
            elif msg[0] == "reset_stream":
                stream = worker.streams.get(msg[1])
                if stream is not None:
                    stream.reset()
            else:
                worker.submit(*msg)
    finally:
        worker.stop()
        reg.close()
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(_worker_main(int(sys.argv[1])))
