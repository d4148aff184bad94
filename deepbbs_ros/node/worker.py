"""One registration worker thread fed through a single "latest" slot.

The executor thread hands each synchronised pair to :meth:`LatestSlotWorker.submit` and returns at
once. The worker runs one job at a time; while it is busy, a newer job replaces the pending one and
the replaced job is counted as dropped. The node therefore never builds a backlog: at most one job
runs and one waits, whatever the input rate.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


class LatestSlotWorker:
    """Run ``handler(job)`` on a background thread, newest job wins.

    Args:
        handler: called on the worker thread for every job that is not superseded. Exceptions are
            passed to ``on_error(job, exc)`` and the worker keeps going.
        on_error: see above; default re-raises nothing and ignores the error.
        name: thread name (shows in ``py-spy`` / ``top -H``).
    """

    def __init__(
        self,
        handler: Callable[[Any], None],
        on_error: Callable[[Any, BaseException], None] | None = None,
        name: str = "deepbbs-worker",
    ) -> None:
        self._handler = handler
        self._on_error = on_error
        self._cond = threading.Condition()
        self._pending: Any = None
        self._has_pending = False
        self._busy = False
        self._stop = False
        self.submitted = 0
        self.dropped = 0
        self.processed = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, job: Any) -> bool:
        """Put ``job`` in the slot; returns True when it replaced a pending (now dropped) job."""
        with self._cond:
            replaced = self._has_pending
            if replaced:
                self.dropped += 1
            self._pending = job
            self._has_pending = True
            self.submitted += 1
            self._cond.notify()
            return replaced

    @property
    def busy(self) -> bool:
        """True while a job runs or waits."""
        with self._cond:
            return self._busy or self._has_pending

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until no job runs or waits; returns False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not (self._busy or self._has_pending), timeout)

    def stop(self, timeout: float | None = 5.0) -> None:
        """Drop the pending job, let the running one finish, and join the thread."""
        with self._cond:
            self._stop = True
            if self._has_pending:
                self._pending = None
                self._has_pending = False
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._has_pending or self._stop)
                if self._stop:
                    self._cond.notify_all()
                    return
                job, self._pending, self._has_pending = self._pending, None, False
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
