"""How far a sweep's own motion can put a rigid pose from the truth: the verdict's skew check (no ROS).

A raw sweep (per-point times: Livox, Ouster, Hesai, the simulator) is measured while the sensor moves; a rigid pose
fit to the whole sweep matches the sweep at its mean time, so when the sensor turns by ``w`` within the sweep, the
pose is off by about ``w / 2`` from the pose at the stamp (a legged robot's sway, 25-35 deg/s, turns a Livox
Mid-360 by 2.5-3.5 degrees in 0.1 s). Nothing in the calibrated probability sees it: the skewed cloud still fits.

Only sweeps whose times do not follow the azimuth (Livox's non-repetitive patterns: every direction seen at every
time of the sweep) are judged: on a spinning sensor a point's time is a function of its azimuth, so the motion
within the sweep and the scene's shape along the azimuth cannot be told apart (measured: right poses of a VLP-16 in a
corridor and of HDL-32E sectors read 2-20 degrees within the sweep); :class:`~deepbbs_ros.core.sweep.SweepTimes`
tells them apart (None for such a sweep).

The check judges the pose separately along the sweep's time: with the final pose's correspondences (the raw
points, an even subsample, under ``T`` against the other scan's precision-stage cloud: nearest voxel, its normal),
one Gauss-Newton point-to-plane step with the pose's six degrees of freedom **and** their rate over the sweep (the
body twist times the point's time, centred on the mean time: the constant-velocity continuous-time model; the
early and late halves of the sweep judged apart are its two-bin version, which on a spinning sensor sees two
different halves of the scene, each alone often degenerate). The rate block is the motion within the sweep that the
rigid pose could not absorb (against a target skewed by the same motion, the difference of the two: a car turning
steadily passes). Half of it, rotation (deg) and translation (m), minus ``registration.skew_sigmas`` of its standard
error from the step's normal equations, is the least the pose can be off: :meth:`Skew.bends` says whether that
exceeds the tolerance (``registration.success_rot_deg`` / ``success_trans``). Both scans are checked where both
carry times (the target's sweep against the source's cloud under the inverse pose).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from deepbbs_ros.core import anchoring

__all__ = ["Skew", "check", "judge", "sweep_skew"]

MAX_POINTS = 4000  # raw points used (an even subsample in the scan's order): ~2 ms for the search and the step
MIN_MATCHES = 200  # fewer plane matches: no verdict on the skew (None)
SPIN_POINTS = 1000  # points of the subsample whose times are tested against a spinning sweep's (SweepTimes.fit)


@dataclass(frozen=True)
class Skew:
    """The motion within a sweep that a rigid pose could not absorb, as the pose's least error: ``rot_deg`` /
    ``trans_m`` (half the within-sweep rotation / translation, each less ``sigmas`` standard errors, at least 0), the
    estimates themselves (``rot_est_deg``, ``trans_est_m``: half the within-sweep motion) and their standard errors
    (``rot_se_deg``, ``trans_se_m``), the plane matches ``n``, which scan (``"source"``, ``"target"``) and the time
    it took (``ms``)."""

    rot_deg: float
    trans_m: float
    rot_est_deg: float
    trans_est_m: float
    rot_se_deg: float
    trans_se_m: float
    n: int
    scan: str = "source"
    ms: float = 0.0

    def bends(self, rot_tol_deg: float, trans_tol: float) -> bool:
        """The pose cannot be within ``rot_tol_deg`` / ``trans_tol`` m of the truth by this sweep's own motion."""
        return bool(self.rot_deg > rot_tol_deg or self.trans_m > trans_tol)

    def __str__(self) -> str:
        return (f"sweep skew of the {self.scan}: at least {self.rot_deg:.2f} deg / {self.trans_m:.2f} m off "
                f"(estimate {self.rot_est_deg:.2f} deg / {self.trans_est_m:.2f} m, {self.n} matches)")


def sweep_skew(points: np.ndarray, times: np.ndarray, T: np.ndarray, target, dist: float, sigmas: float = 2.0,
               min_range: float = 0.0, threads: int = 1) -> Skew | None:
    """The skew of one sweep (see the module): ``points`` (N, 3) raw, sensor frame, metres, ``times`` (N,) s (any
    origin), under ``T`` (4, 4) ``T_target_source`` against ``target`` (a precision-stage cloud: ``cloud`` with
    normals, ``tree``), matches within ``dist`` m (point-to-plane within ``dist / 2``), points nearer than
    ``min_range`` m left out (the carrier's body). None without times that span the sweep or enough matches."""
    from deepbbs_ros.core.polish_view import PolishView
    from deepbbs_ros.core.sweep import SweepTimes

    t0 = time.perf_counter()
    tt, p = np.asarray(times).reshape(-1), np.asarray(points).reshape(-1, 3)
    if (len(tt) != len(p) or len(p) < MIN_MATCHES or getattr(target, "tree", None) is None
            or isinstance(target, PolishView)):  # a map crop: its tree answers with the map's voxels (not judged)
        return None
    step = max(1, len(p) // MAX_POINTS)
    p, tt = np.asarray(p[::step], np.float64), np.asarray(tt[::step], np.float64)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(tt) & (np.einsum("ij,ij->i", p, p) >= min_range * min_range)
    p, tt = p[ok], tt[ok]
    span = float(np.ptp(tt)) if len(tt) else 0.0
    k = max(1, len(p) // SPIN_POINTS)
    if len(p) < MIN_MATCHES or span <= 0 or SweepTimes.fit(p[::k], tt[::k]) is not None:  # no span, or spinning
        return None
    R, t = np.asarray(T, np.float64)[:3, :3], np.asarray(T, np.float64)[:3, 3]
    moved = p @ R.T + t
    idx, sq = anchoring.nearest(target.tree, moved, threads)
    tpts = np.asarray(target.cloud.points(), np.float64)[idx, :3]
    nrm = np.asarray(target.cloud.normals(), np.float64)[idx, :3]
    r = np.einsum("ij,ij->i", moved - tpts, nrm)  # point-to-plane residual, m
    m = (sq <= dist * dist) & (np.abs(r) <= 0.5 * dist) & (np.einsum("ij,ij->i", nrm, nrm) > 0.5)
    if m.sum() < MIN_MATCHES:
        return None
    p, r, n_src = p[m], r[m], nrm[m] @ R  # the normals in the source frame: a body twist of the sensor
    s = (tt[m] - tt[m].mean()) / span  # the point's time, centred, in sweeps
    J = np.empty((len(p), 12))
    J[:, :3], J[:, 3:6] = n_src, np.cross(p, n_src)  # d r / d (translation, rotation) of the pose
    J[:, 6:] = J[:, :6] * s[:, None]  # ... and of the motion within the sweep
    H = J.T @ J
    H += np.eye(12) * (1e-9 * np.trace(H) / 12)
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    x = -cov @ (J.T @ r)
    sigma2 = float(np.sum((r + J @ x) ** 2) / max(1, len(r) - 12))  # the step's residual variance, m^2
    v, w = x[6:9], x[9:12]  # within the sweep: m, rad
    out = []
    for vec, blk in ((w, slice(9, 12)), (v, slice(6, 9))):
        est = float(np.linalg.norm(vec))
        u = vec / est if est > 0 else np.zeros(3)
        se = float(np.sqrt(max(0.0, sigma2 * u @ cov[blk, blk] @ u)))
        out.append((0.5 * est, 0.5 * se))
    (rot, rot_se), (tr, tr_se) = np.degrees(out[0]), out[1]
    return Skew(max(0.0, float(rot - sigmas * rot_se)), max(0.0, float(tr - sigmas * tr_se)), float(rot), float(tr),
                float(rot_se), float(tr_se), int(m.sum()), ms=(time.perf_counter() - t0) * 1e3)


def check(src_pre, tgt_pre, T: np.ndarray, rc, min_range: float = 0.0, threads: int = 1) -> Skew | None:
    """The larger skew (by its least rotation error, then translation) of the two scans of a pair under ``T`` (4, 4):
    ``src_pre`` / ``tgt_pre`` PreprocessResults that kept their raw points and per-point times (``prepare_scan(points,
    times, stamp_ns)``) and have precision-stage clouds; each scan without times is skipped; None when neither has
    (nothing runs). Matches within ``registration.polish_max_corr_dist`` (GICP's), ``registration.skew_sigmas``."""
    t0 = time.perf_counter()
    found = []
    T = np.asarray(T, np.float64)
    for name, a, b, M in (("source", src_pre, tgt_pre, T), ("target", tgt_pre, src_pre, np.linalg.inv(T))):
        if getattr(a, "times", None) is None or getattr(a, "raw_points", None) is None or b is None:
            continue
        sk = sweep_skew(a.raw_points, a.times, M, b.polish_cloud, rc.polish_max_corr_dist, rc.skew_sigmas,
                        min_range, threads)
        if sk is not None:
            found.append(dataclasses.replace(sk, scan=name))
    if not found:
        return None
    worst = max(found, key=lambda k: (k.bends(rc.success_rot_deg, rc.success_trans), k.rot_deg, k.trans_m))
    return dataclasses.replace(worst, ms=(time.perf_counter() - t0) * 1e3)


def judge(src_pre, tgt_pre, T: np.ndarray, rc, min_range: float = 0.0) -> tuple[bool, str]:
    """The verdict's use of :func:`check`: (whether the pose ``T`` (4, 4) cannot be within ``success_rot_deg`` /
    ``success_trans`` by its sweeps' own motion, what was found: "rejected: ...", "passed: ...", or "" where neither
    scan has per-point times and nothing ran)."""
    sk = check(src_pre, tgt_pre, T, rc, min_range)
    if sk is None:
        return False, ""
    bends = sk.bends(rc.success_rot_deg, rc.success_trans)
    return bends, f"{'rejected' if bends else 'passed'}: {sk}"
