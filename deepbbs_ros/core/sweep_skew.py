"""How far the sweeps' own motion can put a rigid pose from the truth: the verdict's skew check (no ROS).

A raw sweep (per-point times: Livox, Ouster, Hesai, the simulator) is measured while the sensor moves; a rigid pose
fit to the whole sweep matches it at its mean time, so when the sensor turns by ``w`` within the sweep, the sweep sits
``w / 2`` from its pose at the stamp (a legged robot's sway, 25-35 deg/s, turns a Livox Mid-360 by 2.5-3.5 degrees
in 0.1 s). The pair's pose is off by the difference of its two sweeps' half-motions (``xi_s / 2 - Ad(T^-1) xi_t /
2``: two sweeps that turn alike cancel). Nothing in the calibrated probability sees it: a skewed cloud still fits.

Each sweep's motion (:func:`sweep_motion`): with the final pose's correspondences (the raw points, an even subsample,
under ``T`` against the other scan's precision-stage cloud: nearest voxel, its normal), one Gauss-Newton
point-to-plane step with the pose's six degrees of freedom **and** their rate over the sweep (the body twist times
the point's time, centred on the sweep's mean time: the constant-velocity continuous-time model). The early and late
halves judged apart are its two-bin version, each half alone often degenerate. Its rate block is the sensor's
motion within the sweep (against another Livox sweep, whose own skew blurs its surfaces but does not follow the
direction, the sweep's own motion). The pose's error (:func:`check`), less ``registration.skew_sigmas`` standard
errors (from the steps' normal equations), is the least the pose can be off: :meth:`Skew.bends` says whether that
exceeds the tolerance (``registration.success_rot_deg`` / ``success_trans``). A scan without times counts as still.

Only sweeps whose times do not follow the azimuth (Livox's non-repetitive patterns: every direction seen at every
time) are judged: on a spinning sensor a point's time is a function of its azimuth, so the motion within the sweep
and the scene's shape along the azimuth cannot be told apart (measured: right poses of a VLP-16 in a corridor and of
HDL-32E sectors read 2-20 degrees within the sweep); :func:`spinning` tells them apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from deepbbs_ros.core import anchoring
from deepbbs_ros.core.se3_covariance import adjoint

__all__ = ["Skew", "check", "judge", "spinning", "sweep_motion"]

MAX_POINTS = 4000  # raw points used (an even subsample in the scan's order): ~2 ms for the search and the step
MIN_MATCHES = 200  # fewer plane matches: no verdict on the skew (None)
AZIMUTH_BINS = 64  # azimuth sectors in which :func:`spinning` measures the spread of the times


@dataclass(frozen=True)
class Skew:
    """The pose's error that the sweeps' own motion implies: its least error ``rot_deg`` / ``trans_m`` (the estimate
    less ``sigmas`` standard errors, at least 0), the estimate (``rot_est_deg``, ``trans_est_m``) and its standard
    errors (``rot_se_deg``, ``trans_se_m``), the plane matches ``n`` (the fewer of the scans judged), which sweeps were
    judged (``"source"``, ``"target"``, ``"both"``) and the time it took (``ms``)."""

    rot_deg: float
    trans_m: float
    rot_est_deg: float
    trans_est_m: float
    rot_se_deg: float
    trans_se_m: float
    n: int
    scans: str = "source"
    ms: float = 0.0

    def bends(self, rot_tol_deg: float, trans_tol: float) -> bool:
        """The pose cannot be within ``rot_tol_deg`` / ``trans_tol`` m of the truth by the sweeps' own motion."""
        return bool(self.rot_deg > rot_tol_deg or self.trans_m > trans_tol)

    def __str__(self) -> str:
        return (f"sweep skew ({self.scans}): at least {self.rot_deg:.2f} deg / {self.trans_m:.2f} m off "
                f"(estimate {self.rot_est_deg:.2f} deg / {self.trans_est_m:.2f} m, {self.n} matches)")


def sweep_motion(points: np.ndarray, times: np.ndarray, T: np.ndarray, target, dist: float,
                 min_range: float = 0.0, threads: int = 1) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The motion within one sweep (see the module): ``points`` (N, 3) raw, sensor frame, metres, ``times`` (N,) s
    (any origin), under ``T`` (4, 4) ``T_target_source`` against ``target`` (a precision-stage cloud: ``cloud`` with
    normals, ``tree``), matches within ``dist`` m (point-to-plane within ``dist / 2``), points nearer than
    ``min_range`` m left out (the carrier's body) -> (the twist (6,) from the sweep's start to its end, body frame:
    translation m, rotation rad; its covariance (6, 6); plane matches). None without times that span the sweep, for a
    spinning sensor's (:func:`spinning`), a map crop or too few matches."""
    from deepbbs_ros.core.polish_view import PolishView

    tt, p = np.asarray(times).reshape(-1), np.asarray(points).reshape(-1, 3)
    if (len(tt) != len(p) or len(p) < MIN_MATCHES or getattr(target, "tree", None) is None
            or isinstance(target, PolishView)):  # a map crop: its tree answers with the map's voxels (not judged)
        return None
    step = max(1, len(p) // MAX_POINTS)
    p, tt = np.asarray(p[::step], np.float64), np.asarray(tt[::step], np.float64)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(tt) & (np.einsum("ij,ij->i", p, p) >= min_range * min_range)
    p, tt = p[ok], tt[ok]
    span = float(np.ptp(tt)) if len(tt) else 0.0
    if len(p) < MIN_MATCHES or span <= 0 or spinning(p, tt):  # no span, or a spinning sensor's sweep
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
    return x[6:], sigma2 * cov[6:, 6:], int(m.sum())


def spinning(points: np.ndarray, times: np.ndarray) -> bool:
    """Whether a sweep's times follow the azimuth (a spinning sensor, whole or a sector of it): within each of
    :data:`AZIMUTH_BINS` azimuth sectors (with at least 5 of ``points`` (N, 3)) the times (N,) spread (standard
    deviation, median over the sectors) under a tenth of the sweep's span; a non-repetitive pattern sees every
    direction at every time (about 0.29 of the span)."""
    az = np.arctan2(points[:, 1], points[:, 0])
    b = np.minimum((az + np.pi) / (2 * np.pi) * AZIMUTH_BINS, AZIMUTH_BINS - 1).astype(np.int64)
    n = np.bincount(b, minlength=AZIMUTH_BINS)
    t = times - times.mean()
    mean = np.bincount(b, t, AZIMUTH_BINS) / np.maximum(n, 1)
    sd = np.sqrt(np.maximum(np.bincount(b, t * t, AZIMUTH_BINS) / np.maximum(n, 1) - mean * mean, 0.0))
    full = n >= 5
    return bool(full.any() and np.median(sd[full]) < 0.1 * np.ptp(times))


def check(src_pre, tgt_pre, T: np.ndarray, rc, min_range: float = 0.0, threads: int = 1) -> Skew | None:
    """The pose error ``T`` (4, 4) gets from the motion within the pair's sweeps: ``src_pre`` / ``tgt_pre``
    PreprocessResults that kept their raw points and per-point times (``prepare_scan(points, times, stamp_ns)``) and
    have precision-stage clouds; a scan without times (or not judged: :func:`sweep_motion`) counts as still; None when
    neither is judged (nothing runs). Matches within ``registration.polish_max_corr_dist`` (GICP's);
    ``registration.skew_sigmas``."""
    t0 = time.perf_counter()
    T = np.asarray(T, np.float64)
    Ti = np.linalg.inv(T)
    err, cov, n, names = np.zeros(6), np.zeros((6, 6)), [], []
    for name, a, b, M in (("source", src_pre, tgt_pre, T), ("target", tgt_pre, src_pre, Ti)):
        if getattr(a, "times", None) is None or getattr(a, "raw_points", None) is None or b is None:
            continue
        mo = sweep_motion(a.raw_points, a.times, M, b.polish_cloud, rc.polish_max_corr_dist, min_range, threads)
        if mo is None:
            continue
        xi, c, k = mo
        A = 0.5 * (np.eye(6) if name == "source" else -adjoint(Ti))  # the target's, in the source's frame
        err, cov = err + A @ xi, cov + A @ c @ A.T
        n.append(k)
        names.append(name)
    if not names:
        return None
    out = []
    for blk in (slice(3, 6), slice(0, 3)):  # rotation, translation
        est = float(np.linalg.norm(err[blk]))
        u = err[blk] / est if est > 0 else np.zeros(3)
        se = float(np.sqrt(max(0.0, u @ cov[blk, blk] @ u)))
        out.append((est, se))
    (rot, rot_se), (tr, tr_se) = np.degrees(out[0]), out[1]
    return Skew(max(0.0, float(rot - rc.skew_sigmas * rot_se)), max(0.0, float(tr - rc.skew_sigmas * tr_se)),
                float(rot), float(tr), float(rot_se), float(tr_se), min(n), "both" if len(names) == 2 else names[0],
                (time.perf_counter() - t0) * 1e3)


def judge(src_pre, tgt_pre, T: np.ndarray, rc, min_range: float = 0.0) -> tuple[bool, str]:
    """The verdict's use of :func:`check`: (whether the pose ``T`` (4, 4) cannot be within ``success_rot_deg`` /
    ``success_trans`` by its sweeps' own motion, what was found: "rejected: ...", "passed: ...", or "" where neither
    scan is judged and nothing ran)."""
    sk = check(src_pre, tgt_pre, T, rc, min_range)
    if sk is None:
        return False, ""
    bends = sk.bends(rc.success_rot_deg, rc.success_trans)
    return bends, f"{'rejected' if bends else 'passed'}: {sk}"
