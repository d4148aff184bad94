"""The node's preprocessing on arrival (no ROS import): :func:`arrival_preprocess` (what the inputs call) and
:class:`PreprocessCache`, its results kept by the points' content, shared by the node's inputs (node/inputs.py)."""

from __future__ import annotations

import functools
import threading
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.inputs import BadInput

__all__ = ["PP_CACHE", "PreprocessCache", "arrival_preprocess"]

PP_CACHE = 4  # preprocessed clouds kept by content: a target reused as the next source is free


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
