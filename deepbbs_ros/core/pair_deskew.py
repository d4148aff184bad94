"""The deskew stage of a pair: GICP again on both scans deskewed with their own velocities, when they agree (no ROS).

A scan's ``deskewed_cloud`` is its precision-stage cloud deskewed with its stream's velocity (``core.deskew``,
``core.scans.deskew_prepared``). Both or neither are used: one deskewed scan against a raw one adds distortion. A
velocity biased by traffic moving with the sensor disagrees with the pair's mean motion over the stamp gap: then the
raw clouds are kept. ``register()``'s full pipeline and its good start share this stage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.core.network import orthonormalize
from deepbbs_ros.core.polish import polish

__all__ = ["again", "velocity_off"]

# a scan's own velocity (its stream's) agrees with the pair's mean motion within these (m/s + share of the
# speed, rad/s): a pair up to 5 m apart spans ~0.5 s, over which braking at 2.5 m/s^2 changes the speed ~1 m/s
DESKEW_TOL_SPEED, DESKEW_TOL_REL, DESKEW_TOL_TURN = 1.5, 0.1, np.radians(10.0)


def again(a: Any, b: Any, T: np.ndarray, rc: Any, applied: bool = True) -> tuple[np.ndarray, str, int]:
    """GICP from ``T`` (4, 4) on the ``deskewed_cloud`` s of the source and target ``PreprocessResult`` s ``a``, ``b``
    when both have one, ``applied`` (the precision stage's pose was taken) and their velocities agree with ``T``.
    -> (the pose, what happened (``RegistrationResult.deskew``: "" when neither scan is deskewed), GICP iterations)."""
    if a.deskewed_cloud is None and b.deskewed_cloud is None:
        return T, "", 0
    if a.deskewed_cloud is None or b.deskewed_cloud is None:
        return T, "one scan has no velocity yet: raw clouds", 0
    if not applied:
        return T, "precision stage not applied: raw clouds", 0
    off = velocity_off(a, b, T)
    if off:
        return T, off, 0
    pol = polish(a.deskewed_cloud, b.deskewed_cloud, T, rc)
    if not pol.applied:
        return T, f"precision stage on the deskewed clouds rejected ({pol.reason}): raw clouds", pol.iterations
    T = pol.T_target_source
    T[:3, :3] = orthonormalize(T[:3, :3])
    return T, "deskewed", pol.iterations


def velocity_off(a: Any, b: Any, T: np.ndarray) -> str:
    """"" when both scans' own velocities agree with the pair's mean motion ``T`` (4, 4) over their stamp gap (equal
    stamps: two sensors, no check), else which one is off and by how much."""
    dt = (a.stamp_ns - b.stamp_ns) * 1e-9
    if abs(dt) <= 1e-3:
        return ""
    mean = _twist(T, dt)
    for name, pre in (("source", a), ("target", b)):
        dv, dw = np.linalg.norm((_twist(*pre.velocity) - mean).reshape(2, 3), axis=1)
        if dv > DESKEW_TOL_SPEED + DESKEW_TOL_REL * np.linalg.norm(mean[:3]) or dw > DESKEW_TOL_TURN:
            return f"{name} velocity off the pair's by {dv:.1f} m/s, {np.degrees(dw):.1f} deg/s: raw clouds"
    return ""


def _twist(T: np.ndarray, dt: float) -> np.ndarray:
    """(6,) mean velocity (v m/s, w rad/s; body frame, first order) of the motion T (4, 4) over dt s."""
    from scipy.spatial.transform import Rotation

    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()]) / dt
