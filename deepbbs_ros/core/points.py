"""The one check every public entry point that takes a point cloud runs first (no ROS import).

``DeepBBSRegistration.register`` / ``preprocess`` / ``polish_cloud``, ``register_pair``,
``core.preprocess.preprocess``, ``core.polish.prepare_polish_cloud`` / ``polish``,
``DeepBBSOdometry.register_frame`` and the baselines (``SmallGicpRegistration``, ``KissICPOdometry``)
accept exactly the same clouds:

* an array-like of shape **(N, 3)**: x, y, z in metres. Anything else is refused with a
  :class:`~deepbbs_ros.errors.RegistrationError` naming the shape. Clouds with more columns are not
  cut silently: a KITTI ``.bin`` scan is (N, 4) (x, y, z, reflectance), an organised cloud (H, W, 3),
  and guessing which columns hold xyz would turn a wrong layout into a wrong pose with
  ``converged=True``. Pass ``points[:, :3]`` or ``points.reshape(-1, 3)`` when that is what you mean.
* a real numeric dtype (integers or floats; converted to float32 / float64 as the stage needs). Booleans,
  complex numbers, strings, objects and structured arrays are refused naming the dtype.
* at least one point (an empty cloud is refused as such).
* NaN / Inf: in **raw scans** a non-finite row marks a missing return (drivers write NaN); such rows are
  dropped, as the PointCloud2 decoder drops them, and the stage then needs enough finite points in its
  crop range. **Preprocessed** clouds (``register(..., preprocessed=True)``) are the network's exact input:
  a non-finite coordinate there is refused.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.errors import RegistrationError

__all__ = ["as_transform", "as_xyz"]


def as_xyz(points: Any, name: str = "points", *, dtype: Any = np.float32, finite: bool = False,
           min_points: int = 1) -> np.ndarray:
    """``points`` as a C-contiguous (N, 3) array of ``dtype`` (no copy when it already is one).

    Args:
        points: the cloud (numpy array or anything ``np.asarray`` takes).
        name: what the error messages call it (``"source"``, ``"target"``, ``"preprocess"`` ...).
        dtype: the returned float dtype; None keeps a float dtype as it is (integers become float64).
        finite: refuse NaN/Inf coordinates (preprocessed clouds); False leaves such rows for the stage's
            crop to drop (raw scans).
        min_points: refuse fewer points than this (1: only empty clouds).

    Raises:
        RegistrationError: not (N, 3), not a real numeric dtype, empty, fewer than ``min_points``
            points, or (``finite``) a NaN/Inf coordinate; the message names ``name`` and the shape / dtype.
    """
    try:
        arr = np.asarray(points)
    except (TypeError, ValueError) as err:  # ragged lists and the like
        raise RegistrationError(f"{name}: expected an (N, 3) point array, got {type(points).__name__} ({err})") from err
    kind = arr.dtype.kind
    if arr.dtype.names is not None or kind not in "iuf":
        raise RegistrationError(
            f"{name}: expected a real numeric (N, 3) point array, got dtype {arr.dtype}"
            + (" (a structured array: stack its x, y, z fields)" if arr.dtype.names else "")
        )
    if arr.ndim != 2 or arr.shape[1] != 3:
        hint = ""
        if arr.ndim == 2 and arr.shape[1] > 3:
            hint = "; pass xyz only (e.g. points[:, :3] for KITTI's x, y, z, reflectance)"
        elif arr.ndim > 2 and arr.shape[-1] == 3:
            hint = "; flatten an organised cloud with points.reshape(-1, 3)"
        raise RegistrationError(f"{name}: expected an (N, 3) point array, got shape {arr.shape}{hint}")
    n = arr.shape[0]
    if n == 0:
        raise RegistrationError(f"{name}: empty point cloud (shape {arr.shape})")
    if n < min_points:
        raise RegistrationError(f"{name}: at least {min_points} points are needed, got {n}")
    if dtype is None:
        dtype = arr.dtype if kind == "f" else np.float64
    out = np.ascontiguousarray(arr, dtype=dtype)
    if finite and not np.isfinite(out).all():
        bad = int((~np.isfinite(out).all(axis=1)).sum())
        raise RegistrationError(f"{name}: the point cloud contains NaN or infinite coordinates ({bad} of {n} points)")
    return out


def as_transform(T: Any, name: str = "T_init") -> np.ndarray:
    """An initial guess as a (4, 4) float64 array; RegistrationError naming ``name`` when it is not a
    finite (4, 4) matrix (a flat 16-vector is refused rather than guessed row- or column-major)."""
    arr = np.asarray(T, dtype=np.float64)
    if arr.shape != (4, 4):
        raise RegistrationError(f"{name}: expected a (4, 4) transform, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise RegistrationError(f"{name}: the transform contains NaN or infinite values")
    return arr
