"""Short ``repr`` for the result dataclasses that hold arrays (no ROS import).

``print(result)`` shows one line a person can read: a (4, 4) transform as its translation and rotation
angle, other arrays as shape and dtype (a handful of values are shown as they are), floats to four
significant digits. Use the attributes (``result.gamma``, ``result.T_target_source``) for the numbers::

    RegistrationResult(T_target_source=T(t=[0.671, 0.012, -0.003] m, rot=1.02 deg), converged=True, ...,
                       gamma=array(shape=(512,), dtype=float32), inlier_ratio=0.9141, ...)
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

__all__ = ["short_repr", "short_value"]

_SMALL = 6  # arrays, lists and dicts up to this many items are shown in full


def short_value(value: Any) -> str:
    """One value as :func:`short_repr` shows it."""
    if isinstance(value, np.ndarray):
        if value.shape == (4, 4) and value.dtype.kind == "f" and np.isfinite(value).all():
            t = ", ".join(f"{x:.3f}" for x in value[:3, 3])
            cos = np.clip((np.trace(value[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
            return f"T(t=[{t}] m, rot={np.degrees(np.arccos(cos)):.2f} deg)"
        if value.size <= _SMALL and value.ndim <= 1:
            return "[" + ", ".join(short_value(x.item()) for x in value) + "]"
        return f"array(shape={value.shape}, dtype={value.dtype})"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    if isinstance(value, dict):
        if len(value) > 2 * _SMALL:
            return f"dict(len={len(value)})"
        return "{" + ", ".join(f"{k!r}: {short_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        if len(value) > _SMALL:
            return f"{type(value).__name__}(len={len(value)})"
        inner = ", ".join(short_value(v) for v in value)
        return f"[{inner}]" if isinstance(value, list) else f"({inner}{',' if len(value) == 1 else ''})"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return f"{type(value).__name__}(...)"
    if hasattr(value, "shape") and hasattr(value, "dtype"):  # a torch tensor
        return f"{type(value).__name__}(shape={tuple(value.shape)}, dtype={value.dtype})"
    return repr(value)


def short_repr(self: Any) -> str:
    """``__repr__`` for a dataclass: its ``repr=True`` fields, each through :func:`short_value`."""
    parts = (f"{f.name}={short_value(getattr(self, f.name))}" for f in dataclasses.fields(self) if f.repr)
    return f"{type(self).__name__}({', '.join(parts)})"
