"""The registration process's fallback (no ROS import): once the worker is lost (it died, stopped answering or could
not be reached), :class:`~deepbbs_ros.node.registration_process.RegistrationProcess` logs one line, stops it, and
runs every request in the node's process from then on, with a ``DeepBBSRegistration`` of its own built on the first
such request; a handle of the dead worker is preprocessed again there from its points, once (nothing is lost but
time), and each input topic's ``StreamDeskew`` starts again there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.scan_handle import ScanHandle, _RemoteStreamDeskew


class LocalFallback:
    """The fallback half of ``RegistrationProcess`` (a base class of it): what it does in the node's process. It reads
    the proxy's ``config``, ``weights``, ``_state``, ``_log``, ``_link`` and keeps ``_local`` (the registration, under
    ``_local_lock``, which also guards the change of ``_state`` to "failed")."""

    config: Any
    weights: str
    _state: str
    _local: Any
    _local_lock: Any
    _link: Any
    _log: Any

    def _local_preprocess(self, points: np.ndarray, times: Any, stamp_ns: Any, motion: Any, defer: bool, lazy: bool,
                          driver: str | None) -> ScanHandle:
        """``preprocess`` in this process -> a handle with no worker id."""
        local = self._fallback()
        h = ScanHandle(0, points, times, stamp_ns, local=local.preprocess(points, times, stamp_ns, motion,
                                                                          defer=defer and local.defers_precision,
                                                                          lazy=lazy, driver=driver))
        h.driver = driver
        return h

    def _local_deskew(self, stream: _RemoteStreamDeskew, pre: ScanHandle) -> ScanHandle:
        """A topic's deskew in this process (its ``StreamDeskew`` built here on first use) -> a handle."""
        local = self._fallback()
        if stream._local is None:
            from deepbbs_ros.core.deskew import StreamDeskew

            stream._local = StreamDeskew(local)
        h = ScanHandle(0, pre.xyz, pre.times, pre.stamp_ns, local=stream._local.apply(self._localized(pre)))
        h.driver = pre.driver
        return h

    def _localized(self, h: ScanHandle) -> Any:
        """The handle's PreprocessResult in this process (preprocessed again once, after a fallback)."""
        if h.local is None:
            local = self._fallback()
            h.local = local.preprocess(h.xyz, h.times, h.stamp_ns, defer=local.defers_precision, lazy=True,
                                       driver=h.driver)
        return h.local

    def _failed(self, err: Exception) -> None:
        """Log once, stop the worker and register in this process from now on."""
        with self._local_lock:
            if self._state == "failed":
                return
            stopping = self._state == "stopped"
            self._state = "failed"
        if not stopping:
            self._log(f"{err}: registering in the node's process from now on")
        self._link.stop()

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
