#!/usr/bin/env python3
"""How far GICP from the truth settles on a pair of raw (skewed) sweeps, and how far once each scan is deskewed.

For each ``--rigs`` entry ``SENSOR:MOUNT:PLACE`` the simulator (``--seed``; seeds of calibrate_verdict.py's rigs are
``seed * 100 + rig index``) records the same frames twice, keeping the motion skew of each sweep and compensated; on
pairs 1, 3, 6 and 10 frames apart the precision stage's GICP (core/polish.py, one thread) runs from the truth on:

* ``raw``: the skewed sweeps, as a lone pair has them;
* ``pair_mean``: both deskewed with the pair's mean motion over the stamp gap, the true one (the best a pair's own
  motion can give);
* ``sweep``: each deskewed with its own velocity from its own sweep (:func:`sweep_velocity`: the early half of the
  sweep registered to the late half), from GICP's raw answer;
* ``compensated``: the compensated sweeps (the simulator's truth).

Per pair the rotation error (deg) of each, and the CPU of the two sweep velocities over the raw GICP's (same process,
one thread). With ``--thirds`` a sweep velocity is kept only where the sweep's thirds agree on the turn
(:func:`thirds_agree`). ``verdict``: the good start's verdict (core/calibrated.py,
``registration.good_start_probability``) on calibrate_verdict.py's poses of each pair (GICP from the truth moved a
little and far, the truth moved beyond 2 deg / 0.5 m), judged as they are on the raw sweeps (``raw``) and, with
``sweep``, GICP again from each on the sweeps deskewed with their own velocities and judged on those (the moved truths
judged there as they are), and ``choose``: the more probable of the two: wrong (beyond 2 deg / 0.5 m) accepted and
right (1 deg / 0.3 m) rejected, per rig and in all. ::

    python scripts/benchmarks/sweep_velocity.py --rigs mid360:legged:hall avia:handheld:hall --seed 39 --pairs 8 \\
        --out results/sweep_velocity
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402,F401  (puts the checkout first on sys.path)
from scipy.spatial.transform import Rotation  # noqa: E402

from deepbbs_ros.core import within  # noqa: E402
from deepbbs_ros.core.polish import MIN_POLISH_POINTS, polish  # noqa: E402
from deepbbs_ros.core.preprocess import SweepTimes  # noqa: E402
from deepbbs_ros.errors import RegistrationError  # noqa: E402

WAYS = ("raw", "sweep", "choose")
COUNTS = ("poses", "right", "wrong", "wrong_accepted", "right_rejected")


MAX_TURN_RATE = np.radians(360.0)  # rad/s; a faster half-to-half turn is a failed alignment, not a motion
#: the half-to-half turn is a motion only when it stands out of its own uncertainty: its Mahalanobis distance
#: squared (3 degrees of freedom) over chi2(3) at 99 %; under it the sweep is taken as still (no deskew)
SIGNIFICANT = 11.345


def sweep_velocity(config: Any, pre: Any) -> tuple[np.ndarray, float] | None:
    """The velocity of a prepared scan that kept its raw points and per-point times (``prepare_scan(points, times,
    stamp_ns)``) as ``(T_early_late (4, 4), seconds between the halves' median times)``, the form
    ``core.scans.deskew_prepared`` takes, ``T_early_late`` the identity when the turn does not stand out of its
    uncertainty (the half-sweeps' GICP covariance, core/within.py: a corridor's halves hardly pin a rotation); None
    for a spinning sensor, a half too sparse, or GICP not converging."""
    pts, t = pre.raw_points, pre.times
    if pts is None or t is None or len(t) < 4 * MIN_POLISH_POINTS or SweepTimes.fit(pts, t) is not None:
        return None
    from deepbbs_ros.core.scans import polish_cloud

    half = float(np.median(t))
    early, late = t < half, t >= half
    try:
        ce, cl = polish_cloud(config, pts[early]), polish_cloud(config, pts[late])
    except RegistrationError:
        return None
    res = polish(cl, ce, np.eye(4), config.registration)
    dt = float(np.median(t[late]) - np.median(t[early]))
    if not res.applied or dt <= 0:
        return None
    T = res.T_target_source
    turn = np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
    if turn / dt > MAX_TURN_RATE:
        return None
    C = within.pose_covariance(cl, ce, T, config.registration.polish_max_corr_dist)
    w = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    try:
        d2 = float(w @ np.linalg.solve(C[3:, 3:], w)) if C is not None else 0.0
    except np.linalg.LinAlgError:
        d2 = 0.0
    return (T, dt) if d2 > SIGNIFICANT else (np.eye(4), dt)


def thirds_agree(config: Any, pre: Any, velocity: tuple[np.ndarray, float]) -> bool:
    """Whether the turn rates of the sweep's first and last two thirds (each its later third registered to its
    earlier one) differ by no more than the rate ``velocity`` measured over its halves: a motion the whole sweep
    shows, not one that a half-sweep's GICP made up (``--thirds``)."""
    from deepbbs_ros.core.scans import polish_cloud

    pts, t = pre.raw_points, pre.times
    q1, q2 = np.quantile(t, [1.0 / 3.0, 2.0 / 3.0])
    parts = [t < q1, (t >= q1) & (t < q2), t >= q2]
    rates = []
    for a, b in zip(parts[:-1], parts[1:]):
        try:
            res = polish(polish_cloud(config, pts[b]), polish_cloud(config, pts[a]), np.eye(4), config.registration)
        except RegistrationError:
            return False
        if not res.applied:
            return False
        d = float(np.median(t[b]) - np.median(t[a]))
        rates.append(Rotation.from_matrix(res.T_target_source[:3, :3]).as_rotvec() / d)
    w = Rotation.from_matrix(velocity[0][:3, :3]).as_rotvec() / velocity[1]
    return bool(np.linalg.norm(rates[0] - rates[1]) <= np.linalg.norm(w))


def deskewed_cloud(config: Any, pre: Any, velocity: tuple[np.ndarray, float]) -> Any:
    """The precision-stage cloud of ``pre`` deskewed with ``velocity`` (:func:`sweep_velocity`): the scan's own
    cloud when the sweep is still (identity)."""
    from deepbbs_ros.core.scans import deskew_prepared

    if np.allclose(velocity[0], np.eye(4)):
        return pre.polish_cloud
    return deskew_prepared(config, pre, velocity).deskewed_cloud


def _rounded(v: Any) -> Any:
    if isinstance(v, float):
        return round(v, 2)
    return [_rounded(x) for x in v] if isinstance(v, list) else v


def main(argv: list[str] | None = None) -> int:
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.core.scans import deskew_prepared
    from deepbbs_ros.metrics.pairs import pair_errors
    from deepbbs_ros.sim.patterns import driver_of
    from deepbbs_ros.sim.rig import make_simulator

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from calibrate_verdict import label, perturb, rows_of

    from deepbbs_ros.core import calibrated
    from deepbbs_ros.core.good_start import good_start_gicp

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rigs", nargs="+", default=["mid360:legged:hall"], help="SENSOR:MOUNT:PLACE (simulated)")
    ap.add_argument("--seed", type=int, default=39, help="the simulator's seed of each rig (default 39)")
    ap.add_argument("--pairs", type=int, default=8, help="pairs per rig (default 8)")
    ap.add_argument("--thirds", action="store_true", help="keep a sweep velocity only where the turn rates of the "
                    "sweep's first and last two thirds agree within it (thirds_agree)")
    ap.add_argument("--out", type=Path, help="write sweep_velocity.json here")
    args = ap.parse_args(argv)
    reg = DeepBBSRegistration(Config())
    cfg, rc = reg.config, reg.config.registration
    rng = np.random.default_rng(args.seed)
    out = {}

    def verdict_counts(src, tgt, src_pc, tgt_pc, Tg) -> dict:
        """The good start's counts on the pair's poses, raw and deskewed (see the module)."""
        src_d, tgt_d = copy.copy(src), copy.copy(tgt)
        src_d.polish_cloud, tgt_d.polish_cloud = src_pc, tgt_pc
        out = {w: dict.fromkeys(COUNTS, 0) for w in WAYS}

        def prob(s_, t_, T):
            return float(calibrated.probability(rows_of(s_, t_, T, rc)[1], "good_start"))

        starts = [perturb(rng, y, t) @ Tg for y, t in (((0, 3), (0, 0.5)), ((10, 45), (1, 4)), ((5, 30), (0.5, 3)))]
        moved = [perturb(rng, (2, 15), (0.5, 2.5)) @ Tg, perturb(rng, (0, 2), (0.6, 1.5)) @ Tg]
        judged = {"raw": [], "sweep": []}  # (label, probability) of each pose, the same order both ways
        for T0 in starts:
            pol = good_start_gicp(src.polish_cloud, tgt.polish_cloud, T0, rc)
            if not pol.applied:
                continue
            again = good_start_gicp(src_pc, tgt_pc, pol.T_target_source, rc)
            for w, (s_, t_), T in (("raw", (src, tgt), pol.T_target_source),
                                   ("sweep", (src_d, tgt_d), again.T_target_source if again.applied else
                                    pol.T_target_source)):
                judged[w].append((label(T, Tg)[0], prob(s_, t_, T)))
        for T in moved:
            for w, (s_, t_) in (("raw", (src, tgt)), ("sweep", (src_d, tgt_d))):
                judged[w].append((label(T, Tg)[0], prob(s_, t_, T)))
        # the more consistent of the two answers (its own clouds' probability), as a registration could choose
        judged["choose"] = [max(a, b, key=lambda x: x[1]) for a, b in zip(judged["raw"], judged["sweep"])]
        for w, poses in judged.items():
            for y, p in poses:
                ok = p >= rc.good_start_probability
                out[w]["poses"] += 1
                out[w]["right"] += y == 1
                out[w]["wrong"] += y == 0
                out[w]["wrong_accepted"] += y == 0 and ok
                out[w]["right_rejected"] += y == 1 and not ok
        return out

    def gicp(a, b, T):
        p = polish(a, b, T, rc)
        return p.T_target_source if p.applied else T

    for spec in args.rigs:
        sensor, mount, place = spec.split(":")
        sk = make_simulator(place, args.seed, sensor, mount, frames=60, compensate=False)
        cp = make_simulator(place, args.seed, sensor, mount, frames=60, compensate=True)
        drv, rows = driver_of(sensor), []
        for p in range(args.pairs):
            i = int(rng.integers(0, 48))
            j = i + (1, 3, 6, 10)[p % 4]
            si, sj = sk.scan_at(i), sk.scan_at(j)
            Tg = np.linalg.inv(si.T_world_lidar) @ sj.T_world_lidar
            dt = (sj.stamp_ns - si.stamp_ns) * 1e-9
            tgt = reg.preprocess(si.points, si.point_times(), si.stamp_ns, driver=drv)
            src = reg.preprocess(sj.points, sj.point_times(), sj.stamp_ns, driver=drv)
            ctg = reg.preprocess(cp.scan_at(i).points, driver=drv)
            csr = reg.preprocess(cp.scan_at(j).points, driver=drv)
            t0 = time.perf_counter()
            T_raw = gicp(src.polish_cloud, tgt.polish_cloud, Tg)
            gicp_ms = (time.perf_counter() - t0) * 1e3
            a, b = deskew_prepared(cfg, src, (Tg, dt)), deskew_prepared(cfg, tgt, (Tg, dt))
            T_mean = gicp(a.deskewed_cloud, b.deskewed_cloud, Tg) if a.deskewed_cloud is not None else Tg
            t0 = time.perf_counter()
            vs, vt = sweep_velocity(cfg, src), sweep_velocity(cfg, tgt)
            if args.thirds:  # a turn the thirds of the sweep do not agree on: taken as none
                vs, vt = ((np.eye(4), v[1]) if v is not None and not np.allclose(v[0], np.eye(4))
                          and not thirds_agree(cfg, pre, v) else v for v, pre in ((vs, src), (vt, tgt)))
            vel_ms = (time.perf_counter() - t0) * 1e3
            T_sweep = None
            if vs is not None and vt is not None:
                T_sweep = gicp(deskewed_cloud(cfg, src, vs), deskewed_cloud(cfg, tgt, vt), T_raw)
            T_cmp = gicp(csr.polish_cloud, ctg.polish_cloud, Tg)
            row = {"pair": [i, j], "raw": float(pair_errors(T_raw, Tg)[0]),
                   "pair_mean": float(pair_errors(T_mean, Tg)[0]),
                   "sweep": None if T_sweep is None else float(pair_errors(T_sweep, Tg)[0]),
                   "compensated": float(pair_errors(T_cmp, Tg)[0]), "velocity_over_gicp": vel_ms / max(gicp_ms, 1e-6),
                   "speed": [float(np.linalg.norm(Tg[:3, 3]) / dt)] + [
                       None if v is None else float(np.linalg.norm(v[0][:3, 3]) / v[1]) for v in (vt, vs)],
                   "still": [v is not None and bool(np.allclose(v[0], np.eye(4))) for v in (vt, vs)]}
            if T_sweep is not None:
                clouds = deskewed_cloud(cfg, src, vs), deskewed_cloud(cfg, tgt, vt)
                row["verdict"] = verdict_counts(src, tgt, *clouds, Tg)
            rows.append(row)
            print(spec, json.dumps({k: _rounded(v) for k, v in row.items()}), flush=True)
        summ = {}
        for k in ("raw", "pair_mean", "sweep", "compensated", "velocity_over_gicp"):
            v = [r[k] for r in rows if r[k] is not None]
            summ[k] = [round(min(v), 2), round(float(np.median(v)), 2), round(max(v), 2)] if v else None
        summ["no_sweep_velocity"] = sum(r["sweep"] is None for r in rows)
        summ["verdict"] = {w: {k: sum(r["verdict"][w][k] for r in rows if "verdict" in r) for k in COUNTS}
                           for w in WAYS}
        print(spec, "min / median / max:", json.dumps(summ), flush=True)
        out[spec] = {"pairs": rows, "summary": summ}
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "sweep_velocity.json").write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
