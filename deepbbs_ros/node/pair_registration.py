"""One pair through the node's registration (no ROS import): :func:`register_clouds` (``T_target_source``, the
result, its timings), the pair's covariance, and :class:`PairStart`, the good start a pair of consecutive scans gets
from the last answer (see :mod:`deepbbs_ros.node.pipeline`)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.node.covariance import alignment_quality
from deepbbs_ros.node.inputs import BadInput, Cloud

#: twist covariance when the velocity is unknown (first scan, or two clouds of the same instant)
UNKNOWN_TWIST_COV = 1e6


@dataclass
class Registered:
    """One registration.

    Attributes:
        T: (4, 4) float64 ``T_target_source`` (finite).
        result: the registration's own result (``RegistrationResult`` for DeepBBS++).
        timings_ms: ``register`` (wall time of the call) and ``register.<stage>`` from the result.
    """

    T: np.ndarray
    result: Any
    timings_ms: dict[str, float] = field(default_factory=dict)


def takes_good_start(registration: Any) -> bool:
    """Whether ``registration.register`` takes ``good_start`` (DeepBBS++ and its registration process; not the
    GICP anchor, which always starts from its start)."""
    import inspect

    try:
        return "good_start" in inspect.signature(registration.register).parameters
    except (TypeError, ValueError, AttributeError):
        return False


def register_clouds(registration: Any, source: Cloud, target: Cloud, T_init: np.ndarray | None = None,
                    good_start: bool = False) -> Registered:
    """``registration.register(source.pp, target.pp[, T_init=...][, good_start=True])`` -> :class:`Registered`;
    ``good_start`` (the caller vouches for ``T_init``) is passed only to a registration that takes it.

    Raises:
        BadInput: ``registration_failed`` on RegistrationError or a non-finite transform.
    """
    t0 = time.perf_counter()
    try:
        if T_init is None:
            result = registration.register(source.pp, target.pp)
        elif good_start and takes_good_start(registration):
            result = registration.register(source.pp, target.pp, T_init=T_init, good_start=True)
        else:
            result = registration.register(source.pp, target.pp, T_init=T_init)
    except RegistrationError as err:
        raise BadInput("registration_failed", str(err)) from err
    timings = {"register": (time.perf_counter() - t0) * 1e3}
    for k, v in (getattr(result, "timings_ms", None) or {}).items():
        if k != "total":
            timings[f"register.{k}"] = float(v)
    T = np.asarray(result.T_target_source, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise BadInput("registration_failed", "registration returned a non-finite transform")
    return Registered(T, result, timings)


def registration_covariance(source: Cloud, target: Cloud, reg: Registered) -> np.ndarray:
    """(6, 6) covariance of ``reg.T`` (x, y, z, rot x, rot y, rot z; left perturbation in the target
    frame) from the residuals of the registered (preprocessed) points, :mod:`deepbbs_ros.node.covariance`: the
    clouds the result says it registered (DeepBBS++: its sampled points, or on the good-start path the subsets of
    the GICP clouds its verdict scored), else the preprocessed clouds' points."""
    src, tgt = _registered_points(reg.result, "source"), _registered_points(reg.result, "target")
    if src is None or tgt is None:
        src, tgt = getattr(source.pp, "points", None), getattr(target.pp, "points", None)
    if src is None or tgt is None:  # a registration without sampled points: no residuals to use
        return np.eye(6) * UNKNOWN_TWIST_COV
    q = alignment_quality(
        src,
        tgt,
        reg.T,
        weights=getattr(reg.result, "gamma", None),
        converged=bool(getattr(reg.result, "converged", True)),
    )
    return q.covariance


def _registered_points(result: Any, name: str) -> np.ndarray | None:
    """``result.source`` / ``result.target`` when the result carries them ((N >= 3, 3)), else None."""
    pts = getattr(result, name, None)
    if isinstance(pts, np.ndarray) and pts.ndim == 2 and pts.shape[1] == 3 and len(pts) >= 3:
        return pts
    return None


class PairStart:
    """Pair mode (stamped): the last valid answer as the next pair's good start.

    Consecutive scans (scan k against scan k-1) move about as the last pair did, and two sensors on one vehicle
    keep their mounting: the last answer ``T_target_source`` is a start DeepBBS++ can vouch for
    (``register(..., good_start=True)``: GICP alone from it when its stricter verdict accepts, the full pipeline
    when not). No good start for the first pair, after a pose the verdict rejected, when the frames changed, after
    ``~/reset``, or when the source stamp is more than ``node.good_start_max_gap`` s from the last answer's.
    Thread-safe (the registration thread updates it, ``~/reset`` clears it)."""

    def __init__(self, max_gap_s: float, enabled: bool = True) -> None:
        self.max_gap_ns = int(max_gap_s * 1e9)
        self.enabled = bool(enabled)
        self._lock = threading.Lock()
        self._last: tuple[np.ndarray, str, str, int] | None = None  # (T, source frame, target frame, source stamp)

    def reset(self) -> None:
        with self._lock:
            self._last = None

    def start(self, source: Cloud, target: Cloud) -> np.ndarray | None:
        """The good start for the pair (source, target), or None (no start vouched for: the full pipeline)."""
        with self._lock:
            last = self._last
        if not self.enabled or last is None:
            return None
        T, src_frame, tgt_frame, stamp = last
        frames = (source.frame_id, target.frame_id)
        if (src_frame, tgt_frame) != frames or abs(source.stamp_ns - stamp) > self.max_gap_ns:
            return None
        return T.copy()

    def update(self, source: Cloud, target: Cloud, reg: Registered) -> None:
        """Keep a valid answer as the next start; a rejected one forgets it."""
        with self._lock:
            if getattr(reg.result, "valid", True):
                self._last = (reg.T.copy(), source.frame_id, target.frame_id, int(source.stamp_ns))
            else:
                self._last = None

