"""The node's side of a scan kept in the registration process (:mod:`deepbbs_ros.node.registration_process`):
its handle (:class:`ScanHandle`, the node's ``Cloud.pp``) and an input topic's ``StreamDeskew`` run there."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


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


class _DeskewOwner(Protocol):
    """What a :class:`_RemoteStreamDeskew` asks of the ``RegistrationProcess`` that made it (the process imports this
    module, not the other way)."""

    def _deskew(self, stream: _RemoteStreamDeskew, pre: ScanHandle) -> ScanHandle: ...

    def _send_quiet(self, msg: tuple) -> None: ...


class _RemoteStreamDeskew:
    """``core.deskew.StreamDeskew`` of one input topic, run in the worker (``apply`` / ``reset``)."""

    def __init__(self, owner: _DeskewOwner, key: str) -> None:
        self._owner, self.key = owner, key
        self._local: Any = None  # the fallback's StreamDeskew

    def apply(self, pre: ScanHandle) -> ScanHandle:
        return self._owner._deskew(self, pre)

    def reset(self) -> None:
        if self._local is not None:
            self._local.reset()
        self._owner._send_quiet(("reset_stream", self.key))
