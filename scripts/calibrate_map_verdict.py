#!/usr/bin/env python3
"""Fit the map verdict (core/map_verdict.py) on simulated localizations in prior maps of every kind of place.

For every rig of :data:`RIGS` (road scenes and indoor places, several sensors and mounts) it builds a map from a
recording's every third scan at their true poses (a ``MapLocalizer`` with that trajectory: its places and crops), and
scores poses with known truth of the scans in between (most degraded like real ones: range noise, things seen in one
scan only, the carrier's body; ``scripts/calibrate_verdict.py``'s :func:`degrade`):

* GICP on the nearest place's crop from the truth moved a little (right, mostly) and far (GICP's local minima), run as
  tracking runs it (``core.good_start.from_start``: GICP's own settings, wherever it goes);
* the truth moved beyond 2 degrees / 0.5 m (a wrong pose near the right one); with ``--slid``, also slid 0.6-1.5 m
  along the direction its fit pins least (along a wall, a corridor, a road: it fits as tightly as the right one);
* the search's own answers: GICP from the descriptor's start on the places the ranking puts first (the right place,
  and look-alike places: wrong);
* scans from outside the map (another rig's): the same search, every answer wrong;
* a short map (three scans) that covers part of a scan taken further on: its right pose, and wrong ones.

Right: within 1 degree / 0.3 m of the truth; wrong: beyond 2 degrees or 0.5 m; in between left out. A logistic
regression (classes weighted equally) on :func:`core.calibrated.design` of the features is written to ``--out``
(``results/map_verdict_model.json`` in the working directory unless told); a reliability table (predicted probability
against the share right) is printed. About 5-10 minutes on two cores. The shipped coefficients
(``deepbbs_ros/resources/map_verdict_model.json``) are replaced only when ``--out`` names a file in the package and
``--force`` is given; without it the script refuses before it simulates anything. ::

    python scripts/calibrate_map_verdict.py                  # fit, write results/map_verdict_model.json
    python scripts/calibrate_map_verdict.py --dump rows.npz  # also keep the rows
    python scripts/calibrate_map_verdict.py --rows rows.npz  # refit from kept rows (no simulation)
    python scripts/calibrate_map_verdict.py --out deepbbs_ros/resources/map_verdict_model.json --force  # ship it
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

import _fit_output  # noqa: E402
from calibrate_verdict import body_points, degrade, fit_logistic, label, perturb  # noqa: E402

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.core import acceptance, calibrated, map_verdict  # noqa: E402
from deepbbs_ros.core.good_start import from_start  # noqa: E402
from deepbbs_ros.core.localization import MapLocalizer  # noqa: E402
from deepbbs_ros.core.polish import polish  # noqa: E402
from deepbbs_ros.core.registration import DeepBBSRegistration  # noqa: E402
from deepbbs_ros.sim.rig import make_simulator  # noqa: E402

#: (sensor, mount, place): the road scenes and the indoor places, spinning and solid-state sensors, every mount
RIGS = (
    ("hdl64", "car", "urban"), ("hdl32", "car", "suburban"), ("vlp16", "car", "highway"),
    ("os1_64", "car", "open_road"), ("os1_32", "wheeled", "corridor"), ("avia", "handheld", "courtyard"),
    ("mid360", "legged", "hall"), ("xt32", "wheeled", "garage"), ("os0_64", "legged", "courtyard"),
    ("helios32", "car", "highway"), ("os1_128", "wheeled", "urban"), ("vlp16", "handheld", "hall"),
)
FRAMES = 60  # scans per recording (10 Hz); the map: every MAP_EVERY-th
MAP_EVERY = 3
MAP_RANGE = 50.0  # m, a map scan's points kept this close
QUERIES = 6  # scans in between the map's per rig
FEATURES_USED = map_verdict.names()  # the model's inputs (every feature)
_RC = Config().registration


def _moved(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    return np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]


def _voxel(points: np.ndarray, voxel: float) -> np.ndarray:
    keys = np.floor(points / voxel).astype(np.int64)
    _, idx = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(idx)]


def _searched(loc: MapLocalizer, prep, places: int = 3) -> list[tuple[np.ndarray, object]]:
    """GICP from the descriptor's start on the ``places`` places the ranking puts first -> [(T_map_scan, crop)]."""
    rc = loc.config.registration
    out = []
    centres = loc.description_centres
    for place, _, yaw, centre in loc.rank(loc.describe(prep.points, centres), None, centres)[:places]:
        crop = loc._crop(place)
        T_init = loc._place_start(crop, yaw, centre, None, loc._sensor_height(prep.pre))  # the search's own start
        pol = polish(prep.pre.polish_cloud.complete(), crop.pre.polish_cloud.complete(), T_init, rc)
        out.append((crop.T_map_place @ (pol.T_target_source if pol.applied else T_init), crop))
    return out


def _weakest(prep, crop, T_map_scan: np.ndarray, dist: float) -> np.ndarray:
    """(3,) the unit direction (map axes) along which the scan's points that fit the crop's planes at ``T_map_scan``
    pin its position least (the smallest eigenvector of ``mean(n n^T)`` over their matches' normals: along a wall,
    a corridor, a road with few cross features)."""
    from deepbbs_ros.core.registration import good_start_points

    spc, tpc = prep.pre.polish_cloud.complete(), crop.pre.polish_cloud.complete()
    pts = good_start_points(spc, _RC)
    T = np.linalg.inv(crop.T_map_place) @ T_map_scan
    moved = _moved(pts, T)
    idx, sq = tpc.tree.batch_nearest_neighbor_search(moved, num_threads=1)
    n = tpc.at(np.asarray(idx, np.int64)[np.asarray(sq) <= dist * dist])[1]
    if len(n) < 6:
        return np.array([1.0, 0.0, 0.0])
    return np.linalg.eigh(n.T @ n / len(n))[1][:, 0]


def _nearest_crop(loc: MapLocalizer, T: np.ndarray):
    d = np.linalg.norm(loc.places[:, :2, 3] - T[:2, 3], axis=1)
    return loc._crop(int(np.argmin(d)))


def collect(rigs, seed: int, log=print, slid: bool = False) -> dict[str, np.ndarray]:
    """Feature rows of poses in simulated maps (see the module; ``slid``: with the slid poses) -> {"x", "y", "rot",
    "trans", "rig", "kind"}."""
    cfg = Config()
    reg = DeepBBSRegistration(cfg)
    rc = cfg.registration
    rng = np.random.default_rng(seed)
    out = {k: [] for k in ("x", "y", "rot", "trans", "rig", "kind", "accepted", "turned")}
    outside: list[np.ndarray] = []  # the last rig's query scans: outside the next rig's map

    def add(ri, kind, loc, prep, T, crop, T_gt):
        y, r, t = label(T, T_gt) if T_gt is not None else (0, float("nan"), float("nan"))
        if y < 0:
            return
        x = map_verdict.answer_features(prep.pre, crop, T, cfg, map_normals=True)
        # the localization's acceptance with the shipped coefficients: accepted, then turned away by the check?
        ok = acceptance.accepts(cfg, acceptance.probability(prep.pre, crop, T, cfg))
        turned = ok and acceptance.second_minimum(prep.pre, crop, T, cfg).ambiguous
        for k, v in (("x", x), ("y", y), ("rot", r), ("trans", t), ("rig", ri), ("kind", kind), ("accepted", ok),
                     ("turned", turned)):
            out[k].append(v)

    for ri, (sensor, mount, place) in enumerate(rigs):
        t0 = time.perf_counter()
        sim = make_simulator(place, seed * 100 + ri, sensor, mount, frames=FRAMES, compensate=True)
        rough = rng.random() < 0.7
        body = body_points(rng) if rough else None
        scans = {k: sim.scan_at(k) for k in range(0, FRAMES)}
        keys = list(range(0, FRAMES, MAP_EVERY))
        parts = []
        for k in keys:
            p = scans[k].points
            r = np.linalg.norm(p, axis=1)
            parts.append(_moved(p[(r > 1.0) & (r < MAP_RANGE)], scans[k].T_world_lidar))
        traj = np.array([scans[k].T_world_lidar for k in keys])
        loc = MapLocalizer(_voxel(np.vstack(parts), 0.2).astype(np.float32), cfg, registration=reg, trajectory=traj)
        qs = [k for k in range(1, FRAMES - 1) if k % MAP_EVERY][:: max(1, (FRAMES * 2 // 3) // QUERIES)][:QUERIES]
        mine = []
        for q in qs:
            pts = degrade(scans[q].points, rng, body) if rough else scans[q].points
            mine.append(pts)
            prep = loc.prepare(pts)
            T_gt = scans[q].T_world_lidar
            crop = _nearest_crop(loc, T_gt)
            T_place = np.linalg.inv(crop.T_map_place)
            for kind, yaw, tr in (("near", (0, 3), (0, 0.5)), ("far", (8, 40), (1, 4))):
                pol = from_start(prep.pre.polish_cloud.complete(), crop.pre.polish_cloud.complete(),
                                 T_place @ T_gt @ perturb(rng, yaw, tr), rc)
                if pol.applied:
                    add(ri, kind, loc, prep, crop.T_map_place @ pol.T_target_source, crop, T_gt)
            add(ri, "moved", loc, prep, T_gt @ perturb(rng, (2, 15), (0.5, 3.0)), crop, T_gt)
            add(ri, "moved", loc, prep, T_gt @ perturb(rng, (0, 2), (0.6, 1.5)), crop, T_gt)
            if slid:  # slid along the direction the scan's fit pins least (a wall, a corridor, a road)
                T_slid = T_gt.copy()
                T_slid[:3, 3] += (rng.choice([-1.0, 1.0]) * rng.uniform(0.6, 1.5)
                                  * _weakest(prep, crop, T_gt, rc.verdict_dist))
                add(ri, "slid", loc, prep, T_slid, crop, T_gt)
            for T, c in _searched(loc, prep):
                add(ri, "search", loc, prep, T, c, T_gt)
        for pts in outside[:3]:  # scans from elsewhere: every answer is wrong
            prep = loc.prepare(pts)
            for T, c in _searched(loc, prep, places=2):
                add(ri, "outside", loc, prep, T, c, None)
        outside = mine
        # a short map: three scans; a scan taken further on sees part of it
        a = int(rng.integers(0, FRAMES // 3))
        short = [_moved(scans[k].points, scans[k].T_world_lidar) for k in (a, a + 1, a + 2)]
        far = [b for b in range(a + 6, FRAMES) if 6.0 < np.linalg.norm(
            scans[b].T_world_lidar[:3, 3] - scans[a].T_world_lidar[:3, 3]) < 30.0]
        if far:
            sl = MapLocalizer(_voxel(np.vstack(short), 0.2).astype(np.float32), cfg, registration=reg,
                              trajectory=np.array([scans[k].T_world_lidar for k in (a, a + 1, a + 2)]))
            b = far[len(far) // 2]
            pts = degrade(scans[b].points, rng, body) if rough else scans[b].points
            prep = sl.prepare(pts)
            T_gt = scans[b].T_world_lidar
            crop = _nearest_crop(sl, T_gt)
            pol = from_start(prep.pre.polish_cloud.complete(), crop.pre.polish_cloud.complete(),
                             np.linalg.inv(crop.T_map_place) @ T_gt, rc)
            if pol.applied:
                add(ri, "short", sl, prep, crop.T_map_place @ pol.T_target_source, crop, T_gt)
            add(ri, "short-moved", sl, prep, T_gt @ perturb(rng, (2, 15), (0.5, 3.0)), crop, T_gt)
        n = sum(1 for r in out["rig"] if r == ri)
        log(f"{sensor}/{mount}/{place}{' degraded' if rough else ''}: {n} poses, {time.perf_counter() - t0:.1f} s")
    return {k: np.asarray(v) for k, v in out.items()}


def reliability(p: np.ndarray, y: np.ndarray, edges=(0, 0.05, 0.2, 0.5, 0.7, 0.9, 0.98, 1.0001)) -> list[str]:
    """Lines of a reliability table: per bin of predicted probability, the poses and the share right."""
    lines = ["  p bin        poses  share right  mean p"]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (p >= lo) & (p < hi)
        if m.any():
            lines.append(f"  {lo:.2f}-{min(hi, 1):.2f}  {int(m.sum()):7d}  {y[m].mean():11.3f}  {p[m].mean():6.3f}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=61)
    _fit_output.add_out(ap, "map_verdict_model.json", map_verdict.DEFAULT_PATH)
    ap.add_argument("--dump", type=Path, help="also write the feature rows here (.npz)")
    ap.add_argument("--rigs", type=int, default=len(RIGS), help="the first this many rigs only (a quick try)")
    ap.add_argument("--rows", type=Path, help="refit from rows written by --dump (no simulation)")
    ap.add_argument("--slid", action="store_true", help="also poses slid along their weakest direction (wrong); the "
                    "shipped fit is without them (with them, right poses on straight highways are rejected)")
    args = ap.parse_args(argv)
    _fit_output.check_out(ap, args)
    t0 = time.perf_counter()
    data = dict(np.load(args.rows, allow_pickle=False)) if args.rows else collect(RIGS[:args.rigs], args.seed,
                                                                                         slid=args.slid)
    if args.dump:
        np.savez(args.dump, **data)
    cols = [map_verdict.names().index(n) for n in FEATURES_USED]
    X, y = calibrated.design(data["x"][:, cols]), data["y"].astype(float)
    coef, icpt = fit_logistic(X, y)
    p = 1.0 / (1.0 + np.exp(-(X @ coef + icpt)))
    print(f"{int(y.sum())} right, {int((1 - y).sum())} wrong; highest wrong p {p[y == 0].max():.3f}, "
          f"right under 0.5: {int(np.sum(p[y == 1] < 0.5))}; {time.perf_counter() - t0:.0f} s")
    for kind in np.unique(data["kind"]):
        m = data["kind"] == kind
        print(f"  {kind}: {int(m.sum())} poses, right {int(y[m].sum())}, p of right min "
              f"{p[m & (y == 1)].min() if (m & (y == 1)).any() else float('nan'):.3f}, p of wrong max "
              f"{p[m & (y == 0)].max() if (m & (y == 0)).any() else float('nan'):.3f}")
    if "turned" in data:  # the shipped acceptance on these rows: the map verdict, then the second-minimum check
        acc, turned = data["accepted"].astype(bool), data["turned"].astype(bool)
        print(f"shipped acceptance: right accepted {int(np.sum(acc & (y == 1)))} of {int(y.sum())}, turned away by "
              f"the second-minimum check {int(np.sum(turned & (y == 1)))}; wrong accepted "
              f"{int(np.sum(acc & (y == 0)))} of {int((1 - y).sum())}, turned away {int(np.sum(turned & (y == 0)))}")
        for i in np.flatnonzero(acc & ((y == 0) | turned)):
            print(f"  {RIGS[int(data['rig'][i])]} {data['kind'][i]} right {int(y[i])}: {data['rot'][i]:.2f} deg "
                  f"{data['trans'][i]:.2f} m, {'turned away' if turned[i] else 'accepted'}")
    print("reliability (fitted rows):")
    print("\n".join(reliability(p, y)))
    doc = {"features": list(FEATURES_USED), "transform": calibrated.TRANSFORM, "map_normals": True,
           "coef": [round(float(c), 6) for c in coef], "intercept": round(icpt, 6),
           "fitted_on": f"{len(y)} simulated poses in maps, {len(RIGS)} rigs (sensor/mount/place), seed {args.seed}",
           "command": "python scripts/calibrate_map_verdict.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    _fit_output.write(args.out, json.dumps(doc, indent=1) + "\n")
    map_verdict.load.cache_clear()
    map_verdict.uses_map_normals.cache_clear()
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
