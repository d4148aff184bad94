"""The node's end of the registration process's connection (no ROS import): the worker started and greeted,
requests sent from each node thread's lane, their answers handed back by a reader thread, the handles the node
dropped released with the next request. :class:`~deepbbs_ros.node.registration_process.RegistrationProcess`
owns one.
"""

from __future__ import annotations

import itertools
import threading
import weakref
from collections import deque
from concurrent.futures import Future
from typing import Any

from deepbbs_ros.errors import DeepBBSError, ModelError, RegistrationError
from deepbbs_ros.node.registration_worker import _Expired

RESULT_TIMEOUT_S = 60.0  # one request (a registration with its global search on a busy machine)


class _Lost(RegistrationError):
    """The worker died, stopped answering or could not be reached."""


class WorkerLink:
    """``python -m <module> FD`` on a socket pair (``core.worker_process.spawn_worker``), greeted with ``hello``.

    Attributes:
        proc: the worker's ``subprocess.Popen``; conn: the node's ``Connection``.
        ids: request and handle ids (one counter for both).
        released: handle ids the node dropped (appended from any thread), sent with the next request.
        hello: the worker's ``("ready", ...)`` answer.

    Raises:
        ModelError: the worker did not start (it could not load the checkpoint, or timed out); it is stopped.
    """

    def __init__(self, module: str, what: str, hello: Any, timeout_s: float) -> None:
        from deepbbs_ros.core.worker_process import handshake, spawn_worker, stop_worker

        self.ids = itertools.count(1)
        self.released: deque[int] = deque()
        self._futures: dict[int, Future] = {}
        self._futures_lock = threading.Lock()
        self._send_lock = threading.Lock()
        self.proc, self.conn = spawn_worker(module, what)
        # also when collected, at exit; 5 s: the worker stops its own network process too
        self.stop = weakref.finalize(self, stop_worker, self.conn, self.proc, 5.0, True)
        try:
            self.hello = handshake(self.conn, self.proc, hello, what, timeout_s)
        except ModelError:
            self.stop()
            raise

    def start_reader(self) -> None:
        threading.Thread(target=self._read, name="deepbbs-regproc-reader", daemon=True).start()

    @property
    def waiting(self) -> int:
        """Requests waiting for their answer."""
        with self._futures_lock:
            return len(self._futures)

    def call(self, msg: tuple) -> Any:
        """Send one request from this thread's lane and wait for its answer.

        Raises:
            _Lost: the worker is gone or did not answer in time.
            _Expired: a scan the worker no longer keeps (its id the message).
            RegistrationError: the worker raised one (its message).
        """
        rid = next(self.ids)
        fut: Future = Future()
        with self._futures_lock:
            self._futures[rid] = fut
        released = []
        while self.released:
            released.append(self.released.popleft())
        lane = threading.current_thread().name
        try:
            with self._send_lock:
                if released:
                    self.conn.send(("release", released))
                self.conn.send((rid, lane, msg))
        except (OSError, ValueError) as err:
            with self._futures_lock:
                self._futures.pop(rid, None)
            code = self.proc.poll()
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

    def send_quiet(self, msg: tuple) -> None:
        """Send a message that needs no answer; a failure is left to the next request to find."""
        try:
            with self._send_lock:
                self.conn.send(msg)
        except (OSError, ValueError):
            pass

    def _read(self) -> None:
        """The answers, to the waiting requests; the worker's end to every request still waiting."""
        why = "registration process: connection closed"
        while True:
            try:
                rid, status, value = self.conn.recv()
            except (EOFError, OSError, ValueError):
                code = self.proc.poll()
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
