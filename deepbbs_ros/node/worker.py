"""A worker thread fed through a small bounded queue: the node never builds a backlog.

The executor thread (or an input thread) hands each job to :meth:`LatestSlotWorker.submit` and returns
at once. The worker runs one job at a time; at most ``capacity`` jobs wait behind it. When a job
arrives and the queue is full, the oldest waiting job is dropped and counted. With ``capacity=1``
(the registration worker) this is a "latest" slot: the newest pair wins, whatever the input rate.

Back-pressure: a worker may be given a ``gate`` (another worker's :attr:`LatestSlotWorker.room`): it
starts its next job only while the gate is open. The node's input threads are gated by the
registration worker, so clouds are preprocessed ahead of the registration by at most one pair; when
the registration falls behind, the waiting messages are replaced by newer ones (dropped, counted)
instead of being preprocessed for nothing.
"""

from __future__ import annotations

import ctypes
import sys
import threading
from collections import deque
from collections.abc import Callable
from typing import Any


class LatestSlotWorker:
    """Run ``handler(job)`` on a background thread; newest jobs win when it falls behind.

    Args:
        handler: called on the worker thread for every job that is not dropped. Exceptions are
            passed to ``on_error(job, exc)`` and the worker keeps going.
        on_error: see above; default ignores the error.
        name: thread name (``py-spy`` shows it; on Linux also the OS thread's name, its first 15 characters
            without the ``deepbbs-`` prefix, in ``top -H`` and ``/proc/PID/task/TID/comm``).
        capacity: jobs that may wait while one runs (>= 1); beyond that the oldest waiting one is dropped.
        gate: start a job only while this event is set (jobs keep queueing, and dropping, meanwhile).

    Attributes:
        room: an event set while fewer than ``capacity`` jobs wait (the gate of upstream workers).
    """

    def __init__(
        self,
        handler: Callable[[Any], None],
        on_error: Callable[[Any, BaseException], None] | None = None,
        name: str = "deepbbs-worker",
        *,
        capacity: int = 1,
        gate: threading.Event | None = None,
    ) -> None:
        if capacity < 1:
            raise ValueError(f"worker capacity must be >= 1, got {capacity}")
        self._handler = handler
        self._on_error = on_error
        self._cond = threading.Condition()
        self._pending: deque[Any] = deque()
        self.capacity = int(capacity)
        self._gate = gate
        self.room = threading.Event()
        self.room.set()
        self._busy = False
        self._stop = False
        self.submitted = 0
        self.dropped = 0
        self.processed = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Any) -> bool:
        """Queue ``job``; returns True when the queue was full and its oldest job was dropped."""
        with self._cond:
            replaced = len(self._pending) >= self.capacity
            if replaced:
                self._pending.popleft()
                self.dropped += 1
            self._pending.append(job)
            self.submitted += 1
            if len(self._pending) >= self.capacity:
                self.room.clear()
            self._cond.notify()
            return replaced

    @property
    def busy(self) -> bool:
        """True while a job runs or waits."""
        with self._cond:
            return self._busy or bool(self._pending)

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until no job runs or waits; returns False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not (self._busy or self._pending), timeout)

    def stop(self, timeout: float | None = 5.0) -> None:
        """Drop the waiting jobs, let the running one finish, and join the thread."""
        with self._cond:
            self._stop = True
            self._pending.clear()
            self.room.set()
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def _run(self) -> None:
        _name_os_thread(self._thread.name.removeprefix("deepbbs-"))
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending or self._stop)
                if self._stop:
                    self._cond.notify_all()
                    return
            while self._gate is not None and not self._gate.wait(0.05):  # back-pressure (see module doc)
                if self._stop:
                    break
            with self._cond:
                if self._stop or not self._pending:
                    continue
                job = self._pending.popleft()
                self.room.set()
                self._busy = True
            try:
                self._handler(job)
            except BaseException as exc:  # noqa: BLE001 - the worker must survive any bad job
                if self._on_error is not None:
                    self._on_error(job, exc)
            finally:
                with self._cond:
                    self._busy = False
                    self.processed += 1
                    self._cond.notify_all()


def _name_os_thread(name: str) -> None:
    """Give the calling OS thread ``name`` (Linux ``prctl(PR_SET_NAME)``, 15 characters kept), so that thread
    CPU times can be told apart (``top -H``, ``/proc``); Python 3.11 names only its own thread objects."""
    if not sys.platform.startswith("linux"):
        return
    try:
        ctypes.CDLL(None).prctl(15, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)  # 15 = PR_SET_NAME
    except (OSError, AttributeError):  # no libc symbol: names are cosmetic
        pass
