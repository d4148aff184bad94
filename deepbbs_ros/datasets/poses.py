"""Ground-truth poses and stamps of the readers and writers (no ROS): a track of poses looked up by a scan's stamp
(:class:`PoseTrack`), stamps as exact decimal seconds, poses as ``x y z qx qy qz qw`` rows."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _slerp_T(T0: np.ndarray, T1: np.ndarray, alpha: float) -> np.ndarray:
    """Interpolate two (4, 4) poses: translation linearly, rotation by SLERP; alpha in [0, 1]."""
    from scipy.spatial.transform import Rotation, Slerp

    rots = Rotation.from_matrix(np.stack([T0[:3, :3], T1[:3, :3]]))
    T = np.eye(4)
    T[:3, :3] = Slerp([0.0, 1.0], rots)([alpha]).as_matrix()[0]
    T[:3, 3] = (1.0 - alpha) * T0[:3, 3] + alpha * T1[:3, 3]
    return T


class PoseTrack:
    """Ground-truth poses ``T_world_lidar`` sorted by stamp, looked up by a scan's header stamp.

    Matching rule (:meth:`lookup`): a pose whose stamp equals the scan's is used as is; otherwise,
    when the scan stamp lies between two poses that are both within ``tolerance_ns`` of it, the pose
    is interpolated (translation linearly, rotation by SLERP); otherwise the nearest pose within
    ``tolerance_ns`` is used; otherwise there is no ground truth for that scan (None).
    """

    def __init__(self, stamps_ns: Sequence[int], poses: Sequence[np.ndarray], tolerance_ns: int) -> None:
        order = np.argsort(np.asarray(stamps_ns, dtype=np.int64), kind="stable")
        self.stamps_ns: list[int] = [int(stamps_ns[i]) for i in order]
        self.poses = [np.asarray(poses[i], dtype=np.float64) for i in order]
        self.tolerance_ns = int(tolerance_ns)

    def __len__(self) -> int:
        return len(self.poses)

    def add(self, stamp_ns: int, T: np.ndarray) -> None:
        """Add one pose (poses read in recording order: appended; out of order: inserted)."""
        import bisect

        i = bisect.bisect_right(self.stamps_ns, int(stamp_ns))
        self.stamps_ns.insert(i, int(stamp_ns))
        self.poses.insert(i, np.asarray(T, dtype=np.float64))

    def decided(self, stamp_ns: int) -> bool:
        """True once a pose later than ``stamp_ns + tolerance_ns`` is known: poses still to come (in
        stamp order) cannot change :meth:`lookup` at ``stamp_ns``."""
        return bool(self.stamps_ns) and self.stamps_ns[-1] > stamp_ns + self.tolerance_ns

    def lookup(self, stamp_ns: int) -> np.ndarray | None:
        """(4, 4) float64 ``T_world_lidar`` at ``stamp_ns``, or None when no pose is close enough."""
        import bisect

        if not self.poses:
            return None
        i = bisect.bisect_left(self.stamps_ns, stamp_ns)
        if i < len(self.poses) and self.stamps_ns[i] == stamp_ns:
            return self.poses[i].copy()
        lo, hi = i - 1, i
        d_lo = stamp_ns - self.stamps_ns[lo] if lo >= 0 else None
        d_hi = self.stamps_ns[hi] - stamp_ns if hi < len(self.poses) else None
        ok_lo = d_lo is not None and d_lo <= self.tolerance_ns
        ok_hi = d_hi is not None and d_hi <= self.tolerance_ns
        if ok_lo and ok_hi:
            return _slerp_T(self.poses[lo], self.poses[hi], d_lo / float(d_lo + d_hi))
        if ok_lo:
            return self.poses[lo].copy()
        if ok_hi:
            return self.poses[hi].copy()
        return None


def stamp_to_str(stamp_ns: int) -> str:
    """Seconds as an exact decimal string, ``"1700000000.100000000"`` (no float rounding)."""
    sign = "-" if stamp_ns < 0 else ""
    sec, nsec = divmod(abs(int(stamp_ns)), 1_000_000_000)
    return f"{sign}{sec}.{nsec:09d}"


def parse_stamp(text: str) -> int:
    """Decimal seconds (``"1700000000.1"``, ``"1.7e9"``) to integer nanoseconds, exactly; ValueError."""
    from decimal import Decimal, InvalidOperation

    try:
        value = Decimal(text) * 1_000_000_000
    except InvalidOperation:
        raise ValueError(f"not a number: {text!r}") from None
    if not value.is_finite():
        raise ValueError(f"not a finite time: {text!r}")
    return int(value.to_integral_value())


def T_to_xyzquat(T: np.ndarray) -> np.ndarray:
    """(4, 4) pose -> (7,) float64 ``x y z qx qy qz qw`` (unit quaternion, w >= 0)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(T, dtype=np.float64)[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([np.asarray(T, dtype=np.float64)[:3, 3], q])


def xyzquat_to_T(values: Sequence[float]) -> np.ndarray:
    """``x y z qx qy qz qw`` -> (4, 4) float64 pose; ValueError on a zero or non-finite quaternion.

    The quaternion is normalised first (a pose file's few digits leave its norm off 1), so the rotation
    block is a rotation to about 1e-16 whatever the file held."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(values, dtype=np.float64)
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise ValueError("expected 7 finite numbers x y z qx qy qz qw")
    if np.linalg.norm(v[3:]) < 1e-9:
        raise ValueError("quaternion has zero norm")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:] / np.linalg.norm(v[3:])).as_matrix()
    T[:3, 3] = v[:3]
    return T
