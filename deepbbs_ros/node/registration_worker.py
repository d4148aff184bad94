"""The registration process's side (no ROS import): the node's
:class:`~deepbbs_ros.core.registration.DeepBBSRegistration` and the scans it keeps under their handles, one thread
per lane (a node thread), answering the requests of
:class:`~deepbbs_ros.node.registration_process.RegistrationProcess` (``adopt``, ``deskew``, ``register``, ``kept``;
``release``, ``reset_stream``, ``stop``). Started as ``python -m deepbbs_ros.node.registration_process FD``.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from typing import Any

from deepbbs_ros.core.worker_process import started
from deepbbs_ros.errors import RegistrationError

MAX_SCANS = 16  # scans kept by the worker (the node releases the ones it drops; this bounds a leak)


class _Expired(RegistrationError):
    """A scan the worker no longer keeps (more than :data:`MAX_SCANS` held by the node)."""


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
        self.sources: deque[int] = deque(maxlen=4)  # the last pairs' source scans (a stream's next targets)

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
            if msg[0] == "register" and answer[1] == "ok":
                self.answered(msg)

    def answered(self, msg: tuple) -> None:
        """After an answer was sent: where its target was an earlier pair's source (one stream, scan k against scan
        k-1; not two sensors' scans), the source is the next pair's target: what the verdict reads of it alone is
        built now (core.scans.ready_to_judge), while the lane waits for that pair, off its path."""
        from deepbbs_ros.core.scans import ready_to_judge

        src_id, tgt_id = msg[1], msg[2]
        stream = tgt_id in self.sources
        self.sources.append(src_id)
        with self.scans_lock:
            pre = self.scans.get(src_id) if stream else None
        try:
            if pre is not None:
                ready_to_judge(self.reg.config, pre)
        except Exception:  # noqa: BLE001 - the next registration builds them itself (and says what is wrong)
            pass

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


def _build(weights: str, flat_config: dict[str, Any]) -> tuple[Any, tuple]:
    """The node's registration, warmed up -> (it, the ``("ready", network process state, device)`` answer)."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration

    reg = DeepBBSRegistration(Config.from_flat(flat_config), weights=weights)
    reg.warmup()
    return reg, ("ready", reg.network_process_state, str(reg.device))


def _worker_main(fd: int) -> int:
    """Read (weights, flat config), build and warm up the registration, answer ``("ready", network process
    state, device)``, then serve ``(request id, lane, request)`` messages (and ``("release", ids)``,
    ``("reset_stream", key)``) until ``("stop",)`` or until the node is gone (EOF)."""
    conn, reg, rc = started(fd, _build)
    if reg is None:
        return rc
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
