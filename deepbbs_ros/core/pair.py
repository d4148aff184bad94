"""register_pair: one registration in one call, its DeepBBSRegistration kept between calls (no ROS).

The object behind it is built once per checkpoint file (path, size, modification time), device and
configuration, and the two most recent are kept (loading a checkpoint and warming torch up take ~2 s).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.checkpoint import default_weights_path
from deepbbs_ros.core.registration import DeepBBSRegistration, RegistrationResult

__all__ = ["clear_register_pair_cache", "register_pair"]

_PAIR_CACHE: OrderedDict[tuple, tuple[DeepBBSRegistration, threading.Lock]] = OrderedDict()
_PAIR_CACHE_SIZE = 2  # registrations kept by register_pair (each holds a network and maybe its worker process)
_PAIR_CACHE_LOCK = threading.Lock()


def register_pair(
    source: np.ndarray, target: np.ndarray, config: Config | None = None, **kwargs: Any
) -> RegistrationResult:
    """One-shot convenience: ``DeepBBSRegistration(config, weights=, device=, model=).register(...)``.

    ``weights``, ``device`` and ``model`` go to the constructor, everything else to ``register``.
    The registration object is kept between calls (loading a checkpoint and warming torch up take about
    2 s): calls with the same checkpoint file (path, size and modification time), device and config reuse
    it; the two most recent are kept (:func:`clear_register_pair_cache` drops them and stops their network
    processes). A ``model`` object handed in is used as is and never cached (its weights may change).
    """
    ctor = {k: kwargs.pop(k) for k in ("weights", "device", "model") if k in kwargs}
    if "model" in ctor:
        return DeepBBSRegistration(config, **ctor).register(source, target, **kwargs)
    reg, lock = _cached_registration(config or Config(), ctor.get("weights"), ctor.get("device"))
    with lock:  # one register() at a time per cached object (it may share one network process)
        return reg.register(source, target, **kwargs)


def _cached_registration(config: Config, weights: str | Path | None,
                         device: str | None) -> tuple[DeepBBSRegistration, threading.Lock]:
    path = weights if weights is not None else config.registration.weights
    path = Path(path).expanduser().resolve() if path else default_weights_path()
    try:
        st = path.stat()
        stamp = (st.st_size, st.st_mtime_ns)
    except OSError:
        stamp = None  # the constructor raises ModelError naming the file
    key = (str(path), stamp, device, tuple((k, repr(v)) for k, v in sorted(config.to_flat().items())))
    with _PAIR_CACHE_LOCK:
        hit = _PAIR_CACHE.get(key)
        if hit is not None:
            _PAIR_CACHE.move_to_end(key)
            return hit
    entry = (DeepBBSRegistration(config, weights=path, device=device), threading.Lock())
    evicted = []
    with _PAIR_CACHE_LOCK:
        if key in _PAIR_CACHE:  # another thread built it meanwhile: use that one
            evicted.append(entry)
            entry = _PAIR_CACHE[key]
        else:
            _PAIR_CACHE[key] = entry
        while len(_PAIR_CACHE) > _PAIR_CACHE_SIZE:
            evicted.append(_PAIR_CACHE.popitem(last=False)[1])
    for reg, lock in evicted:
        with lock:  # not in the middle of someone's register()
            reg.close()
    return entry


def clear_register_pair_cache() -> None:
    """Forget the registrations :func:`register_pair` keeps (and stop their network processes)."""
    with _PAIR_CACHE_LOCK:
        entries = list(_PAIR_CACHE.values())
        _PAIR_CACHE.clear()
    for reg, lock in entries:
        with lock:
            reg.close()
