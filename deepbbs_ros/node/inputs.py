"""The node's inputs: every PointCloud2 is decoded, checked and (pair mode, scan-to-scan odometry)
preprocessed on arrival, on its input's own thread, while the registration worker handles the previous
pair (no ROS import). The local-map odometry takes the decoded raw points: its inputs do not preprocess.

::

    executor thread            input thread (one per input topic)
    callback(msg) ─submit──▶   decode → check (frame, stamp) → preprocess (content cache) ─▶ on_cloud(Cloud)
                   bounded:    at most ``capacity`` messages wait per input; a new one drops the oldest
                               waiting one (counted in ``CloudInput.dropped``, on /diagnostics)
                   gated:      a message is taken only while the registration worker has room, so
                               preprocessing runs at most one pair ahead of the registration

Bad input (malformed, empty, NaN-only, too few points, no or changed frame, stamp not increasing,
preprocessing failure) becomes :class:`BadInput` with a kind; the input reports it through
``on_bad(kind, message)`` and goes on with the next message.

Preprocessing depends on the points only, so its results are cached by content (node/preprocess_cache.py: point
count and two checksums of the xyz bytes): a cloud that arrives twice (on both pair inputs, or as the next pair's
target) is preprocessed once, and a second thread asking for a cloud being preprocessed waits for it.
DeepBBS++ with a network process leaves the GICP cloud's k-d tree and covariances to ``register``
(``arrival_preprocess``), which builds them while the network process runs the passes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from deepbbs_ros.node.cloud import BadInput, Cloud, decode_cloud
from deepbbs_ros.node.worker import LatestSlotWorker

__all__ = ["INPUT_QUEUE", "BadInput", "Cloud", "CloudInput", "decode_cloud"]

INPUT_QUEUE = 1  # messages waiting per input while one is preprocessed; more arrivals drop the oldest


class CloudInput:
    """One input topic: a thread that turns each message into a :class:`Cloud` and hands it on.

    Args:
        topic: the resolved topic name (for messages).
        cache: the preprocessing cache shared by the node's inputs (node/preprocess_cache.py ``PreprocessCache``);
            None: no preprocessing on arrival
            (``Cloud.pp`` is None; local-map odometry).
        min_points: clouds with fewer valid points are rejected (``node.min_points``).
        on_cloud: called on the input thread with every good :class:`Cloud`.
        on_bad: ``(kind, message)`` for every rejected message.
        on_error: ``(job, exc)`` for unexpected exceptions (bugs); the thread keeps going.
        increasing_stamps: reject a stamp not after the previous accepted one (odometry input), unless it is
            more than ``jump_back_s`` before it: a time jump (a bag played again), which the node handles.
        capacity: messages that may wait while one is processed; the oldest is dropped beyond that.
        gate: take the next message only while this event is set (the registration worker's ``room``:
            preprocess at most one pair ahead of the registration).
        on_driver: called once, with the driver recognised from the first good message's fields (or None) and that
            message's points, before they are preprocessed (the node logs it, the odometry takes it).
    """

    def __init__(
        self,
        topic: str,
        cache: Any,
        min_points: int,
        on_cloud: Callable[[Cloud], None],
        on_bad: Callable[[str, str], None],
        on_error: Callable[[Any, BaseException], None] | None = None,
        *,
        increasing_stamps: bool = False,
        capacity: int = INPUT_QUEUE,
        gate: threading.Event | None = None,
        deskew: Any = None,
        jump_back_s: float = 1.0,
        on_driver: Callable[[str | None, np.ndarray], None] | None = None,
    ) -> None:
        self._on_driver = on_driver
        self.driver: str | None = None  # the driver recognised from the first good message (node.drivers)
        self._recognised = False
        self._jump_back_ns = int(jump_back_s * 1e9)
        self.topic = topic
        self._cache = cache
        self._deskew = deskew  # core.deskew.StreamDeskew of this topic (DeepBBS++ with a cache), or None
        self._min_points = int(min_points)
        self._on_cloud = on_cloud
        self._on_bad = on_bad
        self._increasing = increasing_stamps
        self._lock = threading.Lock()
        self._frame: str | None = None
        self._last_stamp: int | None = None
        name = "deepbbs-input-" + topic.strip("/").replace("/", "-")
        self._worker = LatestSlotWorker(self._handle, on_error, name=name, capacity=capacity, gate=gate)

    @property
    def dropped(self) -> int:
        """Messages dropped unprocessed because newer ones arrived (oldest first)."""
        return self._worker.dropped

    @property
    def busy(self) -> bool:
        return self._worker.busy

    def submit(self, msg: Any, t_recv: float) -> None:
        """Queue a message received at ``t_recv`` (``time.perf_counter()``); returns at once."""
        self._worker.submit((msg, t_recv))

    def reset(self) -> None:
        """Forget the frame, the last stamp seen and the stream's velocity (``~/reset``)."""
        if self._deskew is not None:
            self._deskew.reset()
        with self._lock:
            self._frame = None
            self._last_stamp = None

    def stop(self) -> None:
        self._worker.stop()

    def _check(self, frame: str, stamp_ns: int) -> None:
        with self._lock:
            known = self._frame if self._frame is not None else frame
            if known != frame:
                raise BadInput(
                    "mismatched_frame",
                    f"{self.topic}: frame_id {frame!r} differs from {known!r} seen before "
                    "(call ~/reset after a deliberate change)",
                )
            last = self._last_stamp
            if self._increasing and last is not None and last - self._jump_back_ns <= stamp_ns <= last:
                raise BadInput(
                    "stamp_not_increasing",
                    f"{self.topic}: stamp {stamp_ns} ns is not after the previous scan's {self._last_stamp} ns "
                    "(call ~/reset after a time jump)",
                )
            self._frame, self._last_stamp = known, stamp_ns

    def _handle(self, job: tuple[Any, float]) -> None:
        msg, t_recv = job
        t0 = time.perf_counter()
        try:
            xyz, times, stamp_ns, frame = decode_cloud(msg, self.topic, self._min_points)
            self._check(frame, stamp_ns)
            if not self._recognised:  # once per topic, from the first good message's fields
                from deepbbs_ros.node.drivers import recognise

                self.driver, self._recognised = recognise(msg), True
                if self._on_driver is not None:
                    self._on_driver(self.driver, xyz)
            t1 = time.perf_counter()
            pp, pp_ms = ((None, 0.0) if self._cache is None
                         else self._cache.get(xyz, f"{frame}@{stamp_ns}", times, stamp_ns, self.driver))
            if self._deskew is not None and pp is not None and times is not None:
                t_d = time.perf_counter()
                pp = self._deskew.apply(pp)  # this topic's velocity; the GICP cloud deskewed with it
                pp_ms += (time.perf_counter() - t_d) * 1e3
        except BadInput as bad:
            self._on_bad(bad.kind, str(bad))
            return
        t_ready = time.perf_counter()
        timings = {"input_wait": (t0 - t_recv) * 1e3, "decode": (t1 - t0) * 1e3}
        if pp_ms > 0:  # computed here, not a cache hit
            timings["preprocess"] = pp_ms
        self._on_cloud(Cloud(xyz, stamp_ns, frame, t_recv, times, pp, t_ready, timings, self.driver))
