"""The odometry's check: when DeepBBS++ and the other starts should look at a frame (no ROS import)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["suspect"]


def suspect(oc, frames: int, scale: float, gap: bool, fit: float, fits: Sequence[float], dev: float = 0.0,
            limit: float = float("inf")) -> str:
    """Why DeepBBS++ should check this frame ("" = it should not), with ``oc`` the ``odometry`` settings, ``frames``
    the frames registered so far and ``fits`` the last fits.

    A stamp gap of up to ``odometry.gap_trust`` periods (one or two dropped scans: a node that was busy
    for a moment) is left to GICP from the prediction scaled to the gap: over a few periods constant
    velocity is off by centimetres, well inside GICP's basin, and the fit check below catches the
    rest (it needs one earlier fit on a gap, three otherwise). Asking DeepBBS++ on every dropped scan
    made a busy node slower exactly when it was behind, so that it dropped more scans. A step ``dev`` metres
    off the prediction, beyond the gate's ``limit``, is checked as well."""
    if oc.deepbbs_init == "never":
        return ""
    if oc.deepbbs_init == "always":
        return "always"
    if gap and scale > oc.gap_trust:
        return f"stamp gap of {scale:.1f} periods"
    if frames == 1:
        return "first motion"
    if dev > limit:
        return f"step {dev:.2f} m off the prediction, gate {limit:.2f} m"
    median = float(np.median(fits)) if len(fits) else float("nan")
    if len(fits) >= (1 if gap else 3) and fit < oc.fit_drop * median:
        why = f"fit {fit:.2f} < {oc.fit_drop} x median {median:.2f}"
        return f"stamp gap of {scale:.1f} periods, {why}" if gap else why
    return ""
