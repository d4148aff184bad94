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

Preprocessing depends on the points only, so its results are cached by content (point count and two
checksums of the xyz bytes): a cloud that arrives twice (on both pair inputs, or as the next pair's
target) is preprocessed once, and a second thread asking for a cloud being preprocessed waits for it.
DeepBBS++ with a network process leaves the GICP cloud's k-d tree and covariances to ``register``
(:func:`arrival_preprocess`), which builds them while the network process runs the passes.
"""

from __future__ import annotations

import functools
import threading
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.datasets.base import time_field, time_offsets
from deepbbs_ros.errors import PointCloudFormatError, RegistrationError
from deepbbs_ros.node.worker import LatestSlotWorker

PP_CACHE = 4  # preprocessed clouds kept by content: a target reused as the next source is free
INPUT_QUEUE = 1  # messages waiting per input while one is preprocessed; more arrivals drop the oldest


class BadInput(Exception):
    """A message or pair the node rejects; ``kind`` names the error class in logs and /diagnostics."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass
class Cloud:
    """A decoded, checked and preprocessed input cloud.

    Attributes:
        xyz: (N, 3) float32 valid points, sensor frame ``frame_id``, metres.
        times: (N,) float64 per-point time offsets from the stamp, seconds, from the driver's time field
            (``datasets.base.time_field``: Velodyne ``time``, Ouster ``t``, Livox / Hesai absolute ``timestamp``);
            None when the cloud has no time field. The local-map odometry
            deskews with its velocity; with ``node.pair_deskew`` each input of pair mode follows its
            topic's velocity (``core.deskew.StreamDeskew``) and deskews the scan's GICP cloud with it.
        stamp_ns: ``header.stamp`` in nanoseconds.
        frame_id: ``header.frame_id`` (never empty).
        t_recv: ``time.perf_counter()`` when the message reached the node's callback.
        pp: what ``registration.preprocess(xyz)`` returned (a PreprocessResult for DeepBBS++); None when
            the input does not preprocess (local-map odometry: DeepBBS++ preprocesses only when consulted).
        t_ready: ``time.perf_counter()`` when preprocessing finished.
        timings_ms: ``input_wait`` (callback -> input thread), ``decode``, ``preprocess`` (absent on a
            cache hit).
        driver: the driver that publishes the topic (``node.drivers.recognise``, from its first message), or None.
    """

    xyz: np.ndarray
    stamp_ns: int
    frame_id: str
    t_recv: float
    times: np.ndarray | None = None
    pp: Any = None
    t_ready: float = 0.0
    timings_ms: dict[str, float] = field(default_factory=dict)
    driver: str | None = None


def decode_cloud(msg: Any, topic: str, min_points: int) -> tuple[np.ndarray, np.ndarray | None, int, str]:
    """PointCloud2 (rclpy or rosbags) -> ((N, 3) float32 valid xyz, (N,) float64 per-point times in
    seconds since the stamp or None, stamp ns, frame id).

    The points are read through a structured dtype over the message buffer (no copy of the buffer,
    :func:`msg_adapters.pointcloud2.pointcloud2_to_arrays`); only the valid points are copied out.
    Times come from the cloud's time field (``datasets.base.time_field``: Velodyne ``time`` s, Ouster ``t`` ns,
    Livox / Hesai absolute ``timestamp``, read as ``Scan.point_times`` reads it), as seconds since the stamp.

    A time field with the same value for every point (e.g. all 0) gives None: it carries no timing.

    Raises:
        BadInput: ``empty_cloud``, ``malformed_cloud``, ``no_valid_points``, ``too_few_points``
            (fewer than ``min_points`` valid points) or ``missing_frame``, with ``topic`` in the message.
    """
    from msg_adapters.pointcloud2 import field_names, pointcloud2_to_arrays

    if int(msg.width) * int(msg.height) == 0 and len(msg.data) == 0:
        raise BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0, no data)")
    declared = set(field_names(msg))
    tname = time_field(declared)
    try:
        arr = pointcloud2_to_arrays(msg, (tname,) if tname else ())
    except PointCloudFormatError as err:
        raise BadInput("malformed_cloud", f"{topic}: {err}") from err
    n_decl = int(msg.width) * int(msg.height)
    n = int(arr.xyz.shape[0])
    if n_decl == 0:
        raise BadInput("empty_cloud", f"{topic}: empty PointCloud2 (width * height = 0)")
    if n == 0:
        raise BadInput("no_valid_points", f"{topic}: none of the {n_decl} points is finite (NaN-only cloud)")
    if n < min_points:
        raise BadInput("too_few_points", f"{topic}: {n} valid points, fewer than node.min_points={min_points}")
    if not arr.frame_id:
        raise BadInput("missing_frame", f"{topic}: header.frame_id is empty")
    times = None
    if tname is not None:
        raw = arr.fields[tname]
        # a count > 1 time field is not a per-point time; one value for every point (a driver without per-point
        # timing writes 0) says nothing about when each point was measured: no times, as without the field
        if raw.ndim == 1 and raw.min() != raw.max():
            times = time_offsets(tname, raw, int(arr.stamp_ns))
    return arr.xyz, times, int(arr.stamp_ns), arr.frame_id


def arrival_preprocess(registration: Any, good_start: bool = False) -> Callable[..., Any]:
    """What the inputs call to preprocess a cloud on arrival: ``registration.preprocess``, with DeepBBS++'s
    precision-stage k-d tree and covariances deferred to its ``register`` when it has a network process
    (``defers_precision``): they are built there while the network runs the passes, so the registration starts
    on a cloud sooner and that small_gicp work (which holds the GIL) runs when the GIL is otherwise idle. Its sampled
    points (ground removal, FPS) wait for their first use (``lazy``): a pair registered from a good start
    (``register(..., good_start=True)``) never needs them; a fallback samples them where it registers. With
    ``good_start`` (the node passes good starts: most pairs run GICP alone, with no network to overlap) the k-d tree
    and covariances are built on arrival, off the registration's path."""
    defer = getattr(registration, "defers_precision", False) and not good_start
    kwargs = {"defer": True} if defer else {}
    if _takes(registration.preprocess, "lazy"):  # the network's points wait for their first use (a good start: never)
        kwargs["lazy"] = True
    return functools.partial(registration.preprocess, **kwargs) if kwargs else registration.preprocess


def _takes(fn: Callable[..., Any], name: str) -> bool:
    import inspect

    try:
        return name in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False


class PreprocessCache:
    """``preprocess(xyz, times, stamp_ns)`` results keyed by the points' content (and the driver); thread-safe, at
    most ``size`` kept.

    Args:
        preprocess: ``((N, 3) float32, (N,) float64 per-point times or None, stamp ns) -> result`` (DeepBBS++
            keeps the raw scan and its times for the deskew stage); may raise :class:`RegistrationError`. When it
            takes ``driver`` (DeepBBS++), a recognised driver is passed to it.
        size: results kept (least recently used evicted).
    """

    def __init__(self, preprocess: Callable[..., Any], size: int = PP_CACHE) -> None:
        self._preprocess = preprocess
        self._takes_driver = _takes(preprocess, "driver")
        self.size = int(size)
        self._lock = threading.Lock()
        self._entries: OrderedDict[tuple, Future] = OrderedDict()
        self.hits = 0
        self.misses = 0

    @staticmethod
    def key(xyz: np.ndarray) -> tuple[int, int, int]:
        """(points, CRC-32, Adler-32) of the xyz bytes: the same points give the same result."""
        buf = memoryview(np.ascontiguousarray(xyz)).cast("B")
        return int(xyz.shape[0]), zlib.crc32(buf), zlib.adler32(buf)

    def get(self, xyz: np.ndarray, label: str, times: np.ndarray | None = None,
            stamp_ns: int | None = None, driver: str | None = None) -> tuple[Any, float]:
        """(result, ms spent here) for ``xyz`` published by ``driver``; computed at most once per content while
        cached.

        Raises:
            BadInput: ``preprocess_failed`` (``label`` names the cloud) when preprocessing raised
                RegistrationError.
        """
        key = self.key(xyz) if driver is None else (*self.key(xyz), driver)
        kwargs = {"driver": driver} if driver is not None and self._takes_driver else {}
        t0 = time.perf_counter()
        with self._lock:
            fut = self._entries.get(key)
            owner = fut is None
            if owner:
                fut = Future()
                self._entries[key] = fut
                while len(self._entries) > self.size:
                    self._entries.popitem(last=False)
                self.misses += 1
            else:
                self._entries.move_to_end(key)
                self.hits += 1
        if owner:
            try:
                fut.set_result(self._preprocess(xyz, times, stamp_ns, **kwargs))
            except BaseException as exc:  # noqa: BLE001 - handed to every waiter, then re-raised below
                fut.set_exception(exc)
                with self._lock:
                    if self._entries.get(key) is fut:
                        del self._entries[key]
        try:
            result = fut.result()
        except RegistrationError as err:
            raise BadInput("preprocess_failed", f"{label}: {err}") from err
        return result, (time.perf_counter() - t0) * 1e3 if owner else 0.0

    def clear(self) -> None:
        with self._lock:
            self._entries.clear()


class CloudInput:
    """One input topic: a thread that turns each message into a :class:`Cloud` and hands it on.

    Args:
        topic: the resolved topic name (for messages).
        cache: the preprocessing cache shared by the node's inputs; None: no preprocessing on arrival
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
        cache: PreprocessCache | None,
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
