#!/usr/bin/env python3
"""Covariances: how honest are the published pose covariances? NEES of the localization's and the odometry's poses.

For every pose with a true pose: the error ``delta = [t_true - t, log(R_true R^T)]`` (core/covariance.py's convention)
and its NEES ``delta^T Sigma^-1 delta``, which is chi-square with 6 degrees of freedom when the covariance is honest;
per data set: N, the mean NEES and the 95 % band of the mean of N chi2(6) (``[chi2.ppf(0.025, 6N) / N,
chi2.ppf(0.975, 6N) / N]``), the median (chi2(6)'s: 5.35), the share above chi2.ppf(0.95, 6) (5 % when honest), and
the same for the position block alone (3 DoF); per axis the median of ``d_i^2 / Sigma_ii`` (chi2(1)'s: 0.455) and
the first row's NEES (for the odometry: its first step, which has no constant-velocity prediction).

* localization: a map of a simulated drive (scans every ``--map-step`` m, true poses) and the scans of a second drive
  in another lane on another day (every ``--query-every`` th), tracked from their true pose moved by a start error
  (``--start-sigma`` m and deg per axis, the tracking prediction's); real scans: the map of the even scans of each
  ``--real`` folder, the odd ones localized from a start error as well.
* odometry: ``DeepBBSOdometry`` on a simulated drive and on each ``--real`` folder; "step" is the NEES of each scan's
  motion ``T_{k-1}_k`` with the step covariance, "accumulated" that of ``T_first_k`` with the covariance the node
  publishes on ``~/odometry`` (the steps' GICP parts composed along the chain, plus the current scan's own sweep error
  once: node/odometry_pipeline.py ``LocalMapOdometry``); ``--pose`` adds the tables of the other models of it:
  "independent" (the held steps composed as independent, without the velocity error they share), "walk" (every step's
  whole covariance, floor included, composed as a random walk), "once" (the current step's whole floor added), "chain"
  (the GICP parts alone, no floor), "origin" (the first motion's floor replaced by the first scan's own error, a bias
  all poses share: the current scan's share of the sweep floor composed at the origin), "ar1" and "ar1origin" (the
  node's and the origin model with the GICP parts' errors an AR(1) per axis, its coefficient measured from the
  deviations from the prediction: models tried), the lag-1 correlation of consecutive step errors per axis (-0.5 where
  each scan's own error dominates and the next step undoes it, 0 for independent steps) and their mean (away from 0: a
  drift the steps share), and the ``position`` line (the steps' position error against what the prediction floor sees
  of it: _position_floor.position_line). Per simulated drive the ``sweep:`` lines show the sweep floor's premises: how
  the step's rotation error follows the true rotation the deskew missed within the sweep (correlation and slope per
  axis), and the step error's and the floor's deviation's mean squares over the missed rotation's (the floor assumes
  0.5 and 0.25), the ``innovations`` line (what the innovations from the constant-velocity prediction show of the
  steps' rotation errors: scripts/benchmarks/_innovations.py); and the covariance's time per scan. Checks:
  ``--sweep-floor`` (other estimates of the sweep floor from the same deviations; ``share``: from each scan's share of
  its sweep's bend, scripts/benchmarks/_sweep_share.py, with its ``sweep: share`` line; ``adaptive``,
  ``adaptive-bound``: its variance scaled to the innovations, core/floor_scale.py, with a ``floor scale`` line),
  ``--ideal-sweeps`` (drives without motion within the sweep), ``--map-covariances``
  (the odometry against the map's planes), ``--position-floor`` (the prediction floor's position part from a
  chi-square estimate that never clips at 0, scripts/benchmarks/_position_floor.py).

Localization checks (models tried, scripts/benchmarks/_localization_variants.py): ``--estimator cr2`` (the
bias-reduced cluster-robust covariance instead of the jackknife), ``--coarse-cell M`` (along each direction the larger
of the cells' and M-m cells' covariance), ``--min-effective-cells`` (where the t stops), ``--directions`` (the poses'
errors along their covariance's eigen-directions by effective cells), ``--map-planes`` (the refinement and the
covariance against the map's planes alone, the scan's own covariances out). Each set prints its poses' mean error per
axis and its t (an error the poses share, which no pose's covariance holds) and their root mean square error and
standard deviation per axis.

Before: ``--before`` scores the point-to-point covariance the node had (node/covariance.py alignment_quality,
localization and odometry) instead of the GICP one.

Calibration check: ``--fit`` fits the one factor on the localization's covariances (core/covariance.py
``LOCALIZATION_INFLATION``, 1: none) that would make the simulated sets' pooled mean NEES 6 (:func:`fit`), and scores
every set with it; the node fits nothing (the leave-one-cell-out covariance needs no factor).

Truth error: the real sets' ground truth is itself off by centimetres (KITTI about 2 cm / 0.05 deg, nuScenes about
5 cm / 0.3 deg: the data's README); the "+truth" columns add that as an isotropic covariance (per axis) to the
estimate's, the plain ones do not.

    python scripts/benchmarks/covariance.py --real PATH/TO/kitti/00 PATH/TO/nuscenes_hdl32
    python scripts/benchmarks/covariance.py --scenes urban --lidars hdl64 --fit      # the factors, quickly
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common
import _localization_variants as _variants

CHI2_MEDIAN_6 = 5.348120627447122  # scipy.stats.chi2.median(6)
#: per-axis (m, deg) error of the real sets' ground truth (the data's README)
TRUTH_SIGMA = {"kitti": (0.02, 0.05), "nuscenes": (0.05, 0.3)}


def nees_stats(rows: list[tuple[np.ndarray, np.ndarray]]) -> dict:
    """[(delta (6,), cov (6, 6))] -> the figures of one set (module docstring)."""
    from scipy.stats import chi2

    if not rows:
        return {"n": 0}
    out: dict = {"n": len(rows)}
    for name, sl, dof in (("pose", slice(0, 6), 6), ("position", slice(0, 3), 3)):
        v = np.array([float(d[sl] @ np.linalg.solve(c[sl, sl], d[sl])) for d, c in rows])
        n = len(v)
        out[name] = {"mean": float(v.mean()), "median": float(np.median(v)),
                     "band": [float(chi2.ppf(0.025, dof * n) / n), float(chi2.ppf(0.975, dof * n) / n)],
                     "above_p95": float(np.mean(v > chi2.ppf(0.95, dof)))}
        out[name]["inside"] = bool(out[name]["band"][0] <= out[name]["mean"] <= out[name]["band"][1])
    # per axis (x, y, z, roll, pitch, yaw): the median of d_i^2 / Sigma_ii (chi2(1)'s: 0.455), and the first row's
    # NEES (the odometry's first step: no prediction)
    axes = np.array([np.square(d) / np.diag(c) for d, c in rows])
    out["axes_median"] = [float(x) for x in np.median(axes, axis=0)]
    out["first"] = float(rows[0][0] @ np.linalg.solve(rows[0][1], rows[0][0]))
    return out


def with_truth(rows, sigma: tuple[float, float] | None):
    if sigma is None:
        return rows
    add = np.diag([sigma[0] ** 2] * 3 + [np.radians(sigma[1]) ** 2] * 3)
    return [(d, c + add) for d, c in rows]


def truth_needed(rows, sigma: tuple[float, float] | None) -> list[tuple[float, float]]:
    """The truth error (m, deg per axis: ``sigma`` scaled) at which the rows' mean NEES falls to the upper edge of
    its band and to 6; [] without a truth error or when the mean is under the edge without one."""
    from scipy.optimize import brentq
    from scipy.stats import chi2

    if sigma is None or len(rows) < 2:
        return []

    def mean(scale: float) -> float:
        return float(np.mean([d @ np.linalg.solve(c, d)
                              for d, c in with_truth(rows, (sigma[0] * scale, sigma[1] * scale))]))

    out = []
    for target in (chi2.ppf(0.975, 6 * len(rows)) / len(rows), 6.0):
        if mean(0.0) <= target or mean(4.0) >= target:
            return out
        scale = brentq(lambda x, t=target: mean(x) - t, 0.0, 4.0)
        out.append((sigma[0] * scale, sigma[1] * scale))
    return out


def _gicp_noise(floor) -> np.ndarray:
    """(3,) rad^2: a MotionFloor's mean GICP variance per rotation axis over its window (0 before any)."""
    return np.mean(np.asarray(floor._noise), axis=0)[3:] if floor._noise else np.zeros(3)


def _rms(x, less=0.0) -> np.ndarray:
    return np.sqrt(np.maximum(np.mean(np.square(np.asarray(x)), axis=0) - less, 0.0))


#: ``--sweep-floor``: MotionFloor._sweep_floor's estimates (checks; "shipped" is the module's own)
SWEEP_FLOORS = {
    "shipped": None,
    "half": lambda f: 0.5 ** 0.5 * _rms(f._swept),
    "sub": lambda f: 2.0 ** 0.5 * _rms(f._swept, _gicp_noise(f)),
    "diff": lambda f: _rms(np.diff(np.asarray(f._swept), axis=0), 2.0 * _gicp_noise(f)) if len(f._swept) > 1
    else np.zeros(3),
    "none": lambda f: np.zeros(3),
    "share": None,  # scripts/benchmarks/_sweep_share.py: each scan's share of its sweep's bend (installed in main)
    "adaptive": None,  # odometry.sweep_floor adaptive: scaled to the innovations (core/floor_scale.py)
    "adaptive-bound": None,  # odometry.sweep_floor adaptive_bound
}


def perturbed(T: np.ndarray, rng, sigma: float) -> np.ndarray:
    """``T`` moved by ``sigma`` m per axis and ``sigma`` deg per rotation axis (normal)."""
    from scipy.spatial.transform import Rotation

    E = np.eye(4)
    E[:3, :3] = Rotation.from_rotvec(np.radians(rng.normal(0, sigma, 3))).as_matrix()
    E[:3, 3] = rng.normal(0, sigma, 3)
    return E @ T


# ---- data ---------------------------------------------------------------------------------------------------------
def sim_sets(args):
    """(name, map points, map poses, [(points, T_map_scan)], drive of (points, times, stamp_ns, T) for odometry)."""
    from deepbbs_ros.sim.patterns import make_sensor
    from deepbbs_ros.sim.simulator import DriveSimulator

    for scene in args.scenes:
        for lidar_name in args.lidars:
            lidar = make_sensor(lidar_name)  # a spinning sensor (sim/patterns.py: hdl64, vlp16, os1_64, xt32...)
            F = args.frames
            sim = DriveSimulator(scene, args.seed, lidar, frames=F, compensate=True)
            P = [sim.pose_at(k) for k in range(F)]
            pts, keys, last = [], [], None
            for k in range(F):
                if last is not None and np.linalg.norm(P[k][:3, 3] - P[last][:3, 3]) < args.map_step:
                    continue
                p = sim.scan_at(k).points
                r = np.linalg.norm(p, axis=1)
                p = p[(r > 2.0) & (r < 80.0)]
                pts.append((p @ P[k][:3, :3].T + P[k][:3, 3]).astype(np.float32))
                keys.append(P[k])
                last = k
            other = DriveSimulator(scene, args.seed, lidar, frames=F, compensate=True, world_frames=F,
                                   lane_offset=None, day=None if getattr(args, "same_day", False) else 2)
            queries = [(other.scan_at(k).points, other.pose_at(k)) for k in range(10, F - 10, args.query_every)]
            raw = DriveSimulator(scene, args.seed + 1, lidar, frames=args.odometry_frames,
                                 motion_distortion=not args.ideal_sweeps)
            drive = []
            for k in range(args.odometry_frames):
                s = raw.scan_at(k)
                times = None if args.ideal_sweeps else s.fields.get("time")  # an ideal sweep needs no deskew
                drive.append((s.points, times, s.stamp_ns, raw.pose_at(k)))
            yield f"sim {scene} {lidar_name}", np.concatenate(pts), np.array(keys), queries, drive, None


def real_sets(args):
    from deepbbs_ros.datasets import open_source

    for folder in args.real:
        scans = list(open_source(folder))
        name = Path(folder).name
        name = f"kitti {name}" if "kitti" in str(folder) else name
        truth = TRUTH_SIGMA["kitti" if "kitti" in str(folder) else "nuscenes"]
        T0 = np.linalg.inv(scans[0].T_world_lidar)
        pts, keys, queries = [], [], []
        for i, s in enumerate(scans):
            T = T0 @ s.T_world_lidar
            if i % 2 == 0:
                r = np.linalg.norm(s.points, axis=1)
                p = s.points[(r > 2.5) & (r < 80.0)]
                pts.append((p @ T[:3, :3].T + T[:3, 3]).astype(np.float32))
                keys.append(T)
            else:
                queries.append((s.points, T))
        drive = [(s.points, s.fields.get("time"), s.stamp_ns, T0 @ s.T_world_lidar) for s in scans]
        yield f"real {name}", np.concatenate(pts), np.array(keys), queries, drive, truth


# ---- runs ---------------------------------------------------------------------------------------------------------
def localization_rows(points, keys, queries, config, args, log=print) -> tuple[list, int]:
    from deepbbs_ros.core.covariance import pose_error
    from deepbbs_ros.core.localization import MapLocalizer

    loc = MapLocalizer(points, config, trajectory=keys)
    rng = np.random.default_rng(args.seed)
    rows, failed, ms, share, directions = [], 0, [], [], []
    for pts, T_true in queries:
        _variants.LAST.clear()
        res = loc.localize(pts, perturbed(T_true, rng, args.start_sigma))
        ms.append(res.timings_ms.get("covariance", np.nan))
        share.append(ms[-1] / res.timings_ms.get("total", np.nan))
        if not res.valid:
            failed += 1
            continue
        if args.before:
            cov = _before_localization(res, pts)
        else:
            cov = res.covariance
        if cov is None:
            failed += 1
            continue
        rows.append((pose_error(T_true, res.T_map_scan), np.asarray(cov)))
        if getattr(args, "directions", False) and _variants.LAST and not args.before:
            directions.append(_variants.direction_rows(rows[-1][0]))
    log(f"    covariance: median {np.nanmedian(ms):.1f} ms a pose, {np.nanmedian(share):.0%} of the pose's time")
    if len(rows) >= 2:  # an error the poses share (one no pose's covariance can hold): mm, mdeg
        e = np.array([d for d, _ in rows]) * np.array([1e3] * 3 + [np.degrees(1.0) * 1e3] * 3)
        mean, sem = e.mean(0), e.std(0, ddof=1) / len(e) ** 0.5
        log("    errors, mean (mm, mdeg) and t (x, y, z, roll, pitch, yaw): "
            + ", ".join(f"{m:+.1f} (t {m / max(t, 1e-12):.1f})" for m, t in zip(mean, sem)))
        sd = np.array([np.sqrt(np.diag(c)) for _, c in rows]) * np.array([1e3] * 3 + [np.degrees(1.0) * 1e3] * 3)
        log("    errors, root mean square (mm, mdeg; x, y, z, roll, pitch, yaw): "
            + ", ".join(f"{v:.1f}" for v in np.sqrt(np.square(e).mean(0)))
            + "; standard deviations, root mean square: "
            + ", ".join(f"{v:.1f}" for v in np.sqrt(np.square(sd).mean(0))))
    if directions:
        log("    " + _variants.direction_table(directions))
    return rows, failed


def _before_localization(res, pts) -> np.ndarray:
    """What the node published before: the point-to-point residual covariance on the crop (node/covariance.py)."""
    from deepbbs_ros.node.covariance import alignment_quality

    q = alignment_quality(np.asarray(pts)[:: max(1, len(pts) // 4000)], res.crop, res.T_map_scan)
    return q.covariance


def odometry_rows(drive, config, args) -> tuple[list, list, list, list, list]:
    """(step rows [(delta, step covariance)], chain [(T_odom_{k-1}, T_{k-1}_k, T_odom_k, true T_first_k)], floors
    [the step's sweep floor term, odometry frame, zeros without one], firsts [the first motion's floor term or None],
    helds [the held steps' shared error the pose gains, ``OdometryStep.covariance_held``, odometry frame, zeros
    without one]) of the scans with a step covariance."""
    from kiss_icp.voxelization import voxel_down_sample

    import deepbbs_ros.core.odometry as odomod
    from deepbbs_ros.core.covariance import pose_error
    from deepbbs_ros.core.odometry import DeepBBSOdometry
    from deepbbs_ros.node.covariance import alignment_quality

    odo = DeepBBSOdometry(config)
    steps, chain, floors, firsts, helds, cov_ms, share = [], [], [], [], [], [], []
    first_floor = {}  # frame -> the first motion's floor term (odometry frame), which its covariance holds
    T_prev, prev_points, T0_true, Tp_true = None, None, None, None
    own = odomod._cov.odometry_covariance

    def timed(*a, **k):  # the covariance's time within the scan's
        from deepbbs_ros.core.covariance import floor_term, quantisation_floor

        t = time.perf_counter()
        if len(a) > 4 and a[4] is None:  # no prediction: the first motion's quantisation floor
            motion = float(np.linalg.norm(np.asarray(a[2])[:3, 3]))
            first_floor[len(outs)] = floor_term(quantisation_floor(a[0], a[3], motion), a[2])
        try:
            return own(*a, **k)
        finally:
            cov_ms.append((time.perf_counter() - t) * 1e3)

    odomod._cov.odometry_covariance = timed
    outs, swept, shares, scales = [], [], [], []
    try:
        for pts, times, stamp, _ in drive:
            t0, n0 = time.perf_counter(), len(cov_ms)
            outs.append(odo.register_frame(pts, times, stamp))
            shares.append(getattr(odo, "share", None))  # --sweep-floor share: the scan's share of its sweep's bend
            scales.append(odo._sweep.last_scale)  # --sweep-floor adaptive: the rotation floor's variance scale
            swept.append(None if odo.swept is None else odo.swept.copy())  # the motion the deskew turned it with
            if len(cov_ms) > n0:
                share.append(cov_ms[-1] / ((time.perf_counter() - t0) * 1e3))
    finally:
        odomod._cov.odometry_covariance = own
    missed = []  # (the step's rotation error, the true rotation the deskew missed within the sweep)
    for i, ((_, _, _, T_true), out, sw) in enumerate(zip(drive, outs, swept)):
        T = out.T_first_k
        if T_prev is not None and sw is not None:
            true_step = np.linalg.inv(Tp_true) @ T_true
            missed.append((pose_error(true_step, out.T_prev_k)[3:], pose_error(true_step, sw)[3:],
                           pose_error(out.T_prev_k, sw)[3:]))
        if T_prev is not None:
            if args.before:  # node/odometry_pipeline.py's point-to-point step covariance as it was
                src = np.asarray(voxel_down_sample(out.points, odo.voxel_size * 1.5))
                step_cov = alignment_quality(src, prev_points, out.T_prev_k).covariance
            elif out.covariance is not None:
                B = np.zeros((6, 6))
                B[:3, :3] = B[3:, 3:] = T_prev[:3, :3].T
                step_cov = B @ out.covariance @ B.T
            else:
                step_cov = None
            if step_cov is not None:
                steps.append((pose_error(np.linalg.inv(Tp_true) @ T_true, out.T_prev_k), step_cov))
                chain.append((T_prev, out.T_prev_k, T, np.linalg.inv(T0_true) @ T_true))
                fl = None if args.before else getattr(out, "covariance_floor", None)
                floors.append(np.zeros((6, 6)) if fl is None else np.asarray(fl))
                firsts.append(None if args.before else first_floor.get(i))
                hd = None if args.before else getattr(out, "covariance_held", None)
                helds.append(np.zeros((6, 6)) if hd is None else np.asarray(hd))
        else:
            T0_true = T_true
        T_prev, prev_points, Tp_true = T, out.points, T_true
    if cov_ms:
        print(f"    odometry covariance: median {np.median(cov_ms):.1f} ms a scan, "
              f"{np.median(share):.0%} of the scan's time", flush=True)
    if args.pose and len(steps) >= 5:  # do the steps' errors undo one another (a scan's own error in two steps)?
        e = np.array([d for d, _ in steps])
        lag = [np.corrcoef(e[1:, i], e[:-1, i])[0, 1] for i in range(6)]
        print("    step errors, lag-1 correlation (x, y, z, roll, pitch, yaw): " + ", ".join(f"{c:.2f}" for c in lag),
              flush=True)
        scale = np.array([1e3] * 3 + [np.degrees(1.0) * 1e3] * 3)  # mm, mdeg
        mean, sem = e.mean(0) * scale, e.std(0) * scale / len(e) ** 0.5
        print("    step errors, mean (mm, mdeg) and t (mean / its standard error): "
              + ", ".join(f"{m:.1f} (t {m / max(s, 1e-12):.1f})" for m, s in zip(mean, sem)), flush=True)
    if args.pose and len(chain) >= 5:  # the position's error against what the prediction floor sees of it
        import _position_floor

        print("    " + _position_floor.position_line(steps, chain, floors), flush=True)
    if args.pose and len(chain) >= 5:  # the ar1 model's coefficient from the deviations, at the drive's end
        rho = ar1_coefficient([c[1] for c in chain])
        print("    ar1: rho from the deviations' lag-1 autocorrelation (x, y, z, roll, pitch, yaw): "
              + ", ".join(f"{c:.2f}" for c in rho), flush=True)
    if len(missed) >= 5:  # the sweep floor's premise: the step's rotation error follows the rotation the deskew missed
        err, miss, dev = (np.array(x) for x in zip(*missed))
        fit = [(np.corrcoef(miss[:, i], err[:, i])[0, 1], np.polyfit(miss[:, i], err[:, i], 1)[0]) for i in range(3)]
        print("    sweep: step rotation error vs the true rotation the deskew missed (roll, pitch, yaw): correlation "
              + ", ".join(f"{c:.2f}" for c, _ in fit) + "; slope " + ", ".join(f"{b:.2f}" for _, b in fit)
              + "; missed rms deg " + ", ".join(f"{x:.3f}" for x in np.degrees(np.sqrt(np.mean(miss ** 2, 0)))),
              flush=True)
        # the floor's two premises as mean squares over the missed rotation's: a step takes half of it (0.5: two
        # scans each off by half their own), the deviation the floor measures shows half of it (0.25: hence its 2)
        m2 = np.maximum(np.mean(miss ** 2, 0), 1e-30)
        print("    sweep: over the missed rotation's mean square (roll, pitch, yaw): step error's "
              + ", ".join(f"{x:.2f}" for x in np.mean(err ** 2, 0) / m2) + " (premise 0.5); the deviation from the "
              "deskew's motion's " + ", ".join(f"{x:.2f}" for x in np.mean(dev ** 2, 0) / m2) + " (premise 0.25)",
              flush=True)
    if len(chain) >= 5 and not args.before:  # what the innovations show of the steps' rotation errors
        import _innovations

        print("    " + _innovations.innovation_line(steps, chain, floors), flush=True)
    if args.sweep_floor.startswith("adaptive"):
        print("    floor scale (the rotation floor's variance, innovations' NIS): median "
              f"{np.median(scales[2:]):.2f}, 10-90 % "
              + "-".join(f"{x:.2f}" for x in np.percentile(scales[2:], [10, 90])), flush=True)
    if len(missed) >= 6 and any(x is not None for x in shares):
        _share_line(shares, missed)
    held = [i for i, h in enumerate(helds) if h.any()]
    print(f"    held steps sharing a velocity error (the 2nd and later of a stretch held in a row): {len(held)} of "
          f"{len(helds)}", flush=True)
    return steps, chain, floors, firsts, helds


def _share_line(shares: list, missed: list) -> None:
    """``--sweep-floor share``: the scans' shares of their sweep's bend against what the steps' rotation errors show:
    the least-squares coefficients of each step's error on the next step's missed rotation and on its own (a sweep
    that starts at the stamp, as the simulator's, spans the motion to the next scan: the first coefficient is then
    minus the scan's share; the second the previous scan's, plus what the map's bent scans add)."""
    a = np.array([x for x in shares if x is not None])
    err, miss = np.array([m[0] for m in missed]), np.array([m[1] for m in missed])
    coef = [np.linalg.lstsq(np.stack([miss[1:, i], miss[:-1, i]], axis=1), err[:-1, i], rcond=None)[0]
            for i in range(3)]
    print("    sweep: share of the bend (roll, pitch, yaw) median " + ", ".join(f"{x:.2f}" for x in np.median(a, 0))
          + " (10-90 % " + ", ".join(f"{p:.2f}-{q:.2f}" for p, q in zip(*np.percentile(a, [10, 90], axis=0)))
          + "); step error on the next and this step's missed rotation " + ", ".join(f"{c[0]:+.2f} {c[1]:+.2f}"
                                                                                       for c in coef), flush=True)


def accumulated(steps: list, chain: list, before: bool = False, floors: list | None = None,
                model: str = "node", firsts: list | None = None, helds: list | None = None) -> list:
    """The accumulated rows [(delta of T_odom_k, its covariance)] (``before``: the SE(3)-adjoint sum of the whole
    step covariances the node had before the GICP covariance). ``model``: "node" (node/odometry_pipeline.py: the steps'
    GICP parts, the step covariance less its sweep floor ``floors[k]``, composed along the chain with the held steps'
    shared error ``helds[k]``, plus the current scan's own share of its floor, ``SCAN_FLOOR_SHARE``), "once" (the same
    with the whole floor), "walk" (the whole step covariances composed as independent), "chain" (the GICP parts
    alone), "origin" (a model tried: the first motion's floor
    ``firsts[k]`` out of the chain, and in its place the first scan's own error, a bias every pose shares, taken
    as the current scan's own share of the sweep floor per axis and composed at the origin), "yaw" (a model tried:
    the first motion's floor kept in roll and pitch only; in position and yaw the first sweep floor measured, at the
    origin), "ar1" and "ar1origin" (models tried: the node's and the "origin" model with the GICP parts' errors
    correlated from step to step as an AR(1) per axis, :func:`ar1_rows`), "independent" (the node's without the held
    steps' shared error ``helds[k]``, ``OdometryStep.covariance_held``: the held steps composed as independent)."""
    from deepbbs_ros.core.covariance import adjoint, compose, pose_error
    from deepbbs_ros.node.pipeline import SCAN_FLOOR_SHARE

    floors = floors or [np.zeros((6, 6))] * len(steps)
    firsts = firsts or [None] * len(steps)
    helds = [np.zeros((6, 6))] * len(steps) if not helds or model in ("independent", "walk") else helds
    if model in ("ar1", "ar1origin"):
        return ar1_rows(steps, chain, floors, firsts, model == "ar1origin")
    rows, cov, quant, swept = [], np.zeros((6, 6)), None, None
    for (_, step_cov), (T_prev, T_step, T, T_true), fl, first, held in zip(steps, chain, floors, firsts, helds):
        if model == "yaw":  # a model tried: the first motion's floor in position and yaw replaced, at the origin,
            # by the first sweep floor measured (its roll and pitch kept: they stand in for the slow pitch error)
            quant = first if first is not None else quant
            if swept is None and first is None and quant is not None and fl.any():
                swept = fl.copy()
            cov = compose(T_prev, cov, T_step, step_cov - _in_prev(T_prev, first if first is not None else fl))
            M = np.zeros((6, 6)) if quant is None else quant.copy()
            if swept is not None:
                rest = [0, 1, 2, 5]
                M[np.ix_(rest, rest)] = swept[np.ix_(rest, rest)]
                M[np.ix_(rest, [3, 4])] = M[np.ix_([3, 4], rest)] = 0.0
            rows.append((pose_error(T_true, T), cov + SCAN_FLOOR_SHARE * fl + compose(np.eye(4), M, T, None)))
            continue
        if before:
            Ad = adjoint(T_prev)
            cov = cov + Ad @ step_cov @ Ad.T
            rows.append((pose_error(T_true, T), cov.copy()))
            continue
        # the floor in scan k-1's frame, as the step covariance (odometry frame -> k-1's: the rotation of T_prev)
        B = np.zeros((6, 6))
        B[:3, :3] = B[3:, 3:] = T_prev[:3, :3].T
        origin = model == "origin" and first is not None
        own = B @ (first if origin else fl) @ B.T
        cov = compose(T_prev, cov, T_step, (step_cov if model == "walk" else step_cov - own) + _in_prev(T_prev, held))
        share = {"node": SCAN_FLOOR_SHARE, "independent": SCAN_FLOOR_SHARE, "once": 1.0,
                 "origin": SCAN_FLOOR_SHARE}.get(model, 0.0)
        out = cov + share * fl
        if origin:  # the first pose: its whole first floor (no sweep floor known yet)
            out = out + first
        elif model == "origin":
            out = out + _own_at_origin(T, fl)
        rows.append((pose_error(T_true, T), out))
    return rows


def _own_at_origin(T: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """The first scan's own error per axis, composed at the origin for the pose ``T``: the scan's share
    (``SCAN_FLOOR_SHARE``) of ``floor``'s (a sweep floor term, odometry frame) variance along each of the scan's axes
    (the "origin" models)."""
    from deepbbs_ros.core.covariance import compose
    from deepbbs_ros.node.pipeline import SCAN_FLOOR_SHARE

    R = T[:3, :3]
    var = np.concatenate([np.diag(R.T @ floor[:3, :3] @ R), np.diag(R.T @ floor[3:, 3:] @ R)])
    return compose(np.eye(4), np.diag(SCAN_FLOOR_SHARE * var), T, None)


#: the AR(1) model's largest coefficient: the accumulated variance of an AR(1) sum grows as n^2 when it nears 1
AR1_MAX = 0.9


def ar1_coefficient(motions: list) -> np.ndarray:
    """(6,) the ar1 model's ``rho`` per axis from the registered motions ``T_{k-1}_k`` so far: ``1 + 2 r`` with ``r``
    the lag-1 autocorrelation of the deviations from the constant-velocity prediction (each motion against the one
    before), clipped to [0, :data:`AR1_MAX`]; zeros before three deviations."""
    from scipy.spatial.transform import Rotation

    if len(motions) < 4:
        return np.zeros(6)
    d = []
    for a, b in zip(motions[:-1], motions[1:]):
        D = np.linalg.solve(a, b)
        d.append(np.concatenate([D[:3, 3], Rotation.from_matrix(D[:3, :3]).as_rotvec()]))
    d = np.array(d)
    r = np.sum(d[1:] * d[:-1], axis=0) / np.maximum(np.sum(d * d, axis=0), 1e-30)
    return np.clip(1.0 + 2.0 * r, 0.0, AR1_MAX)


def ar1_rows(steps: list, chain: list, floors: list, firsts: list, origin: bool = False) -> list:
    """The accumulated rows of the "ar1" models (tried, not shipped): the node's model with the steps' GICP parts
    ``u_k`` (the step covariance less its sweep floor, or less the first motion's floor) an AR(1) per axis of the
    scan, ``z_k = rho z_{k-1} + w_k``, ``u_k = L_k z_k`` (``L_k`` the symmetric root of the GICP part), instead of
    independent; ``rho`` is what the odometry can measure as it runs: a deviation from the constant-velocity
    prediction is ``u_k - u_{k-1}`` plus the true motion's change, and the lag-1 autocorrelation ``r`` of a differenced
    AR(1) is ``-(1 - rho) / 2``, so ``rho = 1 + 2 r`` (clipped to [0, :data:`AR1_MAX`]) from the deviations so far.
    The accumulated error ``e_k = Ja e_{k-1} + Jb u_k`` (``compose``'s Jacobians) has the closed-form recursion
    ``Y_k = Cov(e_k, z_k) = Ja Y_{k-1} D + Jb L_k``, ``V_k = Ja V_{k-1} Ja^T + Jb S_k Jb^T + (Ja Y_{k-1} D L_k^T Jb^T +
    its transpose)`` (``D = diag(rho)``; ``rho = 0``: the node's chain). Plus the current scan's own share of its
    floor, and the first motion's floor composed along the chain as the node does ("ar1") or, ``origin`` ("ar1origin"),
    in its place the first scan's own error at the origin, as the "origin" model."""
    from scipy.linalg import sqrtm

    from deepbbs_ros.core.covariance import compose_jacobians, pose_error
    from deepbbs_ros.node.pipeline import SCAN_FLOOR_SHARE

    rows, V, Y, W, swept = [], np.zeros((6, 6)), np.zeros((6, 6)), np.zeros((6, 6)), None
    for k, ((_, S), (T_prev, T_step, T, T_true), fl, first) in enumerate(zip(steps, chain, floors, firsts)):
        rho = ar1_coefficient([c[1] for c in chain[:k + 1]])
        part = S - _in_prev(T_prev, first if first is not None else fl)
        part = 0.5 * (part + part.T)
        L = np.real(sqrtm(part))
        Ja, Jb = compose_jacobians(T_prev, T_step)
        cross = Ja @ Y @ np.diag(rho) @ L.T @ Jb.T
        V = Ja @ V @ Ja.T + Jb @ part @ Jb.T + cross + cross.T
        Y = Ja @ Y @ np.diag(rho) + Jb @ L
        W = Ja @ W @ Ja.T + (first if first is not None else 0.0)  # the first motion's floor along the chain
        swept = fl.copy() if swept is None and first is None and fl.any() else swept
        out = V + SCAN_FLOOR_SHARE * fl
        if not origin:
            out = out + W
        elif first is not None:
            out = out + first
        elif swept is not None:
            out = out + _own_at_origin(T, swept)
        rows.append((pose_error(T_true, T), 0.5 * (out + out.T)))
    return rows


def _in_prev(T_prev: np.ndarray, fl: np.ndarray) -> np.ndarray:
    """``fl`` (odometry frame) in scan k-1's frame, as the step covariance."""
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = T_prev[:3, :3].T
    return B @ fl @ B.T


def hindsight_rows(steps: list, chain: list, floors: list) -> list:
    """A check with the truth (``--pose``'s ``odometry_step_hindsight``): each step's rotation floor replaced by the
    set's own root mean square rotation error per axis, the best constant a floor could take there, the position's
    floor and the GICP part kept: what an honest rotation floor alone would make of the steps."""
    rot = np.sqrt(np.mean(np.square([d[3:] for d, _ in steps]), axis=0))
    out = []
    for (d, S), (T_prev, _, T, _), fl in zip(steps, chain, floors):
        B = np.zeros((6, 6))
        B[:3, :3] = B[3:, 3:] = T[:3, :3]
        own = np.diag(B.T @ fl @ B).copy()  # the floor's variances along the scan's axes
        own[3:] = np.square(rot)
        out.append((d, S - _in_prev(T_prev, fl) + _in_prev(T_prev, B @ np.diag(own) @ B.T)))
    return out


def fit(rows_by_set: dict, names: list[str]) -> float:
    """The localization's inflation from raw rows (inflation 1) of the simulated sets ``names``: the one factor
    that makes the pooled mean NEES 6 (chi2(6)'s mean, the band's criterion; the medians then show the tails)."""
    return float(np.mean([d @ np.linalg.solve(c, d) for n in names for d, c in rows_by_set[n]]) / 6.0)


def save_rows(path: Path, loc_rows: dict, step_rows: dict, chains: dict, truth: dict) -> None:
    """The raw rows of every set (for --refit)."""
    import json

    path.parent.mkdir(parents=True, exist_ok=True)
    arrays, meta = {}, {"truth": truth, "loc": list(loc_rows), "odo": list(step_rows)}
    for i, rows in enumerate(loc_rows.values()):
        arrays[f"loc{i}_d"] = np.array([d for d, _ in rows]).reshape(-1, 6)
        arrays[f"loc{i}_c"] = np.array([c for _, c in rows]).reshape(-1, 6, 6)
    for i, (name, rows) in enumerate(step_rows.items()):
        arrays[f"odo{i}_d"] = np.array([d for d, _ in rows]).reshape(-1, 6)
        arrays[f"odo{i}_c"] = np.array([c for _, c in rows]).reshape(-1, 6, 6)
        arrays[f"odo{i}_chain"] = np.array([np.stack(c) for c in chains[name]]).reshape(-1, 4, 4, 4)
    np.savez_compressed(path, meta=json.dumps(meta), **arrays)


def load_rows(path: str) -> tuple[dict, dict, dict, dict]:
    import json

    z = np.load(path)
    meta = json.loads(str(z["meta"]))
    truth = {k: (tuple(v) if v is not None else None) for k, v in meta["truth"].items()}
    loc = {n: list(zip(z[f"loc{i}_d"], z[f"loc{i}_c"])) for i, n in enumerate(meta["loc"])}
    odo = {n: list(zip(z[f"odo{i}_d"], z[f"odo{i}_c"])) for i, n in enumerate(meta["odo"])}
    chains = {n: [tuple(c) for c in z[f"odo{i}_chain"]] for i, n in enumerate(meta["odo"])}
    return loc, odo, chains, truth


def report(title: str, figs: dict) -> None:
    print(f"\n{title}")
    print(f"{'set':34s} {'N':>4s} {'mean NEES':>10s} {'95% band':>15s} {'median':>7s} {'>p95':>6s} | "
          f"{'pos mean':>9s} {'band':>13s} {'>p95':>6s}")
    for name, f in figs.items():
        if not f.get("n"):
            print(f"{name:34s}    0")
            continue
        p, q = f["pose"], f["position"]
        print(f"{name:34s} {f['n']:4d} {p['mean']:10.2f} [{p['band'][0]:5.2f}, {p['band'][1]:5.2f}] "
              f"{p['median']:7.2f} {p['above_p95']:6.1%} | {q['mean']:9.2f} [{q['band'][0]:4.2f}, {q['band'][1]:4.2f}]"
              f" {q['above_p95']:6.1%}")
    print("  per axis, median d^2 / var (chi2(1): 0.455)   x      y      z      roll   pitch  yaw   | first row")
    for name, f in figs.items():
        if f.get("n"):
            print(f"  {name:44s}" + " ".join(f"{x:6.2f}" for x in f["axes_median"]) + f" | {f['first']:9.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=["urban", "suburban", "highway", "open_road"])
    ap.add_argument("--lidars", nargs="*", default=["hdl64", "vlp16", "os1_64"],
                    help="spinning sensors (sim/patterns.py)")
    ap.add_argument("--real", nargs="*", default=[], help="KITTI-layout folders with ground truth")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--frames", type=int, default=200, help="frames of each simulated map drive (10 Hz)")
    ap.add_argument("--map-step", type=float, default=2.0, help="m between the map's scans")
    ap.add_argument("--query-every", type=int, default=12, help="every n-th scan of the second drive is a query")
    ap.add_argument("--odometry-frames", type=int, default=60, help="frames of each simulated odometry drive")
    ap.add_argument("--start-sigma", type=float, default=0.2, help="tracking start error, m and deg per axis")
    ap.add_argument("--skip", nargs="*", default=[], choices=["localization", "odometry"])
    ap.add_argument("--pose", action="store_true", help="also the accumulated pose's NEES under the other models: "
                    "independent (the held steps' shared velocity error left out), walk (whole steps composed), "
                    "once (the scan's whole floor added), chain (GICP parts alone), "
                    "origin (the first scan's own error at the origin instead of the first motion's floor), yaw (the "
                    "first motion's floor in position and yaw replaced by the first sweep floor measured, at the "
                    "origin), ar1 (the GICP parts' errors an AR(1) per axis, its coefficient from the deviations' "
                    "lag-1 autocorrelation), ar1origin (ar1 with origin's first floor); and the steps with each set's "
                    "own root mean square rotation error as their rotation floor (hindsight: a check); the raw rows "
                    "kept in OUT/odometry_rows.pkl")
    ap.add_argument("--before", action="store_true", help="score the point-to-point covariance the node had")
    ap.add_argument("--max-points", type=int, default=-1, help="the localization's covariance from every k-th pair, "
                    "at most this many (a check; 0: every pair; default LOCALIZATION_MAX_POINTS, every pair)")
    ap.add_argument("--no-student", action="store_true", help="the localization's covariance not widened as Student's "
                    "t (a check: LOCALIZATION_STUDENT)")
    ap.add_argument("--odometry-max-points", type=int, default=-1, help="the odometry's step covariance from every "
                    "k-th pair, at most this many (a check; 0: every pair; default ODOMETRY_MAX_POINTS)")
    ap.add_argument("--odometry-student", choices=["on", "off"], help="the odometry's step covariance widened as "
                    "Student's t or not (a check; default ODOMETRY_STUDENT)")
    ap.add_argument("--position-floor", choices=["shipped", "posterior", "median"], default="shipped",
                    help="the position part of the odometry's prediction floor: the module's (the missed variance "
                    "clipped at 0) or a chi-square estimate from the window's n deviations (models tried: "
                    "scripts/benchmarks/_position_floor.py)")
    ap.add_argument("--sweep-floor", choices=sorted(SWEEP_FLOORS), default="shipped", help="the odometry's sweep "
                    "floor per rotation axis from the deviations d of the registered motion from the deskew's (a "
                    "check; core/motion_floor.py): shipped (sqrt(2) rms d: d taken as half the missed rotation), half "
                    "(sqrt(2) / 2 rms d: d taken as the whole missed rotation), sub (shipped, less the step's GICP "
                    "variance that d carries), diff (the rms of d's change from scan to scan, less twice that "
                    "variance), none (no sweep floor: the prediction's floor alone), share (each scan's share of its "
                    "sweep's bend from its pairs' Hessian weighted by time in the sweep, bends independent: "
                    "_sweep_share.py), adaptive (shipped, its variance scaled so that the last steps' innovations "
                    "from the constant-velocity prediction have their expected mean NIS: odometry.sweep_floor "
                    "adaptive, core/floor_scale.py), adaptive-bound (the largest scale their NIS does not reject at "
                    "2.5 %%)")
    ap.add_argument("--ideal-sweeps", action="store_true", help="the simulated odometry drives without motion within "
                    "the sweep (every point cast from the pose at the stamp, no per-point times: nothing to deskew; a "
                    "check of what the sweep and its deskew cause)")
    ap.add_argument("--same-day", action="store_true", help="the localization's queries on the map drive's day (its "
                    "parked cars and traffic; default another day: a check of what the changed world causes)")
    ap.add_argument("--map-covariances", action="store_true", help="the odometry aligns against the map's planes "
                    "(odometry.map_covariances; a check)")
    ap.add_argument("--threads", type=int, default=0, help="the odometry's small_gicp threads (0: every core)")
    ap.add_argument("--estimator", choices=["jackknife", "cr2"], default="jackknife", help="the localization's "
                    "cluster-robust covariance: the node's leave-one-cell-out (jackknife) or the bias-reduced CR2 (a "
                    "model tried: scripts/benchmarks/_localization_variants.py)")
    ap.add_argument("--coarse-cell", type=float, default=0.0, help="m: the localization's covariance along each "
                    "direction the larger of the cells' and these coarser cells' (a model tried; 0: off)")
    ap.add_argument("--directions", action="store_true", help="per localization set, the poses' errors along their "
                    "covariance's eigen-directions by the directions' effective cells (which directions are cautious)")
    ap.add_argument("--min-effective-cells", type=float, default=0.0, help="the effective cells at which the "
                    "localization's Student's t stops (a check; default MIN_EFFECTIVE_CELLS)")
    ap.add_argument("--map-planes", action="store_true", help="the localization's refinement and covariance against "
                    "the map's planes alone (point-to-plane on the map crop's normals, the scan's own covariances out: "
                    "a model tried, scripts/benchmarks/_localization_variants.py)")
    ap.add_argument("--cell", type=float, default=0.0, help="m: the cluster cell instead of CLUSTER_CELL (a check)")
    ap.add_argument("--fit", action="store_true", help="the factor on the localization's covariances that would make "
                    "the simulated sets' pooled mean NEES 6 (a check); raw rows kept in OUT/covariance_rows.npz")
    ap.add_argument("--refit", metavar="NPZ", help="fit again from the raw rows of an earlier --fit (no data)")
    ap.add_argument("--out", default="bench_out", help="figures: OUT/covariance.json")
    args = ap.parse_args(argv)

    import deepbbs_ros.core.cluster_robust as robustmod
    import deepbbs_ros.core.covariance as covmod
    from deepbbs_ros.config import Config

    if args.fit:  # raw cluster-robust covariances: inflation 1
        covmod.LOCALIZATION_INFLATION = 1.0
    if args.max_points >= 0:
        covmod.LOCALIZATION_MAX_POINTS = args.max_points
    if args.no_student:
        covmod.LOCALIZATION_STUDENT = False
    if args.odometry_max_points >= 0:
        covmod.ODOMETRY_MAX_POINTS = args.odometry_max_points
    if args.odometry_student:
        covmod.ODOMETRY_STUDENT = args.odometry_student == "on"
    if args.cell > 0:  # read where the cluster-robust covariance is computed
        robustmod.CLUSTER_CELL = args.cell
    if args.min_effective_cells > 0:
        robustmod.MIN_EFFECTIVE_CELLS = args.min_effective_cells
    if args.estimator != "jackknife" or args.coarse_cell > 0 or args.directions:
        _variants.install(args.estimator, args.coarse_cell, args.directions)
    if args.map_planes:
        _variants.install_map_planes()
    if args.position_floor != "shipped":
        import _position_floor

        import deepbbs_ros.core.motion_floor as floormod

        _position_floor.install(floormod, args.position_floor)
    if args.sweep_floor != "shipped" and not args.sweep_floor.startswith("adaptive"):
        import deepbbs_ros.core.motion_floor as floormod

        if args.sweep_floor == "share":
            import _sweep_share

            import deepbbs_ros.core.odometry as odomod

            _sweep_share.install(odomod, floormod)
        else:
            floormod.MotionFloor._sweep_floor = SWEEP_FLOORS[args.sweep_floor]
    config = Config()
    if args.threads > 0:
        config.odometry.threads = args.threads
    config.odometry.map_covariances = config.odometry.map_covariances or args.map_covariances
    if args.sweep_floor.startswith("adaptive"):
        config.odometry.sweep_floor = args.sweep_floor.replace("-", "_")
    loc_rows, step_rows, chains, floors, firsts, helds, truth, notes = {}, {}, {}, {}, {}, {}, {}, {}
    t0 = time.perf_counter()
    if args.refit:
        loc_rows, step_rows, chains, truth = load_rows(args.refit)
        args.fit = True
    for name, points, keys, queries, drive, tsig in ([] if args.refit else [*sim_sets(args), *real_sets(args)]):
        truth[name] = tsig
        if "localization" not in args.skip:
            loc_rows[name], failed = localization_rows(points, keys, queries, config, args)
            notes[name] = f"{failed} of {len(queries)} queries without a pose"
            f = nees_stats(loc_rows[name]) if loc_rows[name] else {}
            print(f"    localization: {notes[name]}; mean NEES {f.get('pose', {}).get('mean', float('nan')):.2f}"
                  + (" (inflation 1)" if args.fit else ""), flush=True)
        if "odometry" not in args.skip:
            step_rows[name], chains[name], floors[name], firsts[name], helds[name] = odometry_rows(drive, config, args)
        print(f"  {name}: done ({time.perf_counter() - t0:.0f} s)", flush=True)
    figures: dict = {}
    if args.fit and not args.refit:
        save_rows(Path(args.out) / "covariance_rows.npz", loc_rows, step_rows, chains, truth)
    if args.pose and step_rows:  # the odometry's raw rows, to compare pose models offline
        import pickle

        Path(args.out).mkdir(parents=True, exist_ok=True)
        with open(Path(args.out) / "odometry_rows.pkl", "wb") as f:
            pickle.dump({"steps": step_rows, "chains": chains, "floors": floors, "firsts": firsts, "helds": helds,
                         "truth": truth}, f)
    if args.fit and loc_rows:
        sims = [n for n in loc_rows if n.startswith("sim")]
        k = fit(loc_rows, sims)
        figures["fit"] = {"localization_inflation": k, "sets": sims}
        for n in loc_rows:
            loc_rows[n] = [(d, k * c) for d, c in loc_rows[n]]
        print(f"\nthe factor the simulated sets would fit on top (the tables below use it): {k:.3f}")
    acc_rows = {n: accumulated(step_rows[n], chains[n], args.before, floors.get(n), helds=helds.get(n))
                for n in step_rows}
    tables = [("localization", loc_rows), ("odometry_step", step_rows), ("odometry_accumulated", acc_rows)]
    if args.pose and not args.before:
        tables += [("odometry_step_hindsight", {n: hindsight_rows(step_rows[n], chains[n], floors[n])
                                                for n in step_rows if len(step_rows[n]) >= 2})]
        tables += [(f"odometry_accumulated_{m}", {n: accumulated(step_rows[n], chains[n], False, floors.get(n), m,
                                                              firsts.get(n), helds.get(n)) for n in step_rows})
                   for m in ("independent", "walk", "once", "chain", "origin", "yaw", "ar1", "ar1origin")]
    label = "before: point-to-point" if args.before else "GICP Hessian" + (", fitted here" if args.fit else "")
    for key, rows in tables:
        figures[key] = {}
        for name, r in rows.items():
            figures[key][name] = nees_stats(r)
            if truth[name] is not None:
                figures[key][name + " +truth"] = nees_stats(with_truth(r, truth[name]))
        if rows:
            report(f"{key} NEES ({label})", figures[key])
    for name, rows in step_rows.items():  # how large a truth error the steps' mean NEES leaves room for
        need = truth_needed(rows, truth[name])
        if need:
            print(f"  odometry {name}: steps inside their band with a truth error per step of "
                  + "; mean 6 with ".join(f"{1e3 * m:.1f} mm / {d:.4f} deg" for m, d in need)
                  + f" (the data's README: {truth[name][0] * 1e3:.0f} mm / {truth[name][1]} deg)")
    for name, note in notes.items():
        print(f"  localization {name}: {note}")
    _common.write_json(Path(args.out), "covariance.json", figures)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
