#!/usr/bin/env python3
"""Fit the calibrated verdict (core/calibrated.py) on simulated pairs of every sensor, mount and place.

For every rig of :data:`RIGS` (each simulated sensor at least once, each mount, each place) it takes pairs of
scans ``gap`` frames apart, prepares them as the registration does, and scores poses with known truth:

* GICP answers (``registration.good_start_*`` limits) from the truth moved a little and from far starts (yaw up to
  45 degrees, up to 4 m): mostly right, and GICP's own local minima (wrong);
* the truth moved beyond 2 degrees / 0.5 m (a wrong pose near the right one);
* another place: a scan far along the same recording as the source, GICP from identity.

With ``--turned-pairs``, pairs of :data:`TURNED_RIGS` whose sensor turned and moved between the scans (sim/turned.py)
add GICP's answers, the truth moved beyond 2 degrees / 0.5 m and the whole pipeline's answer from identity.
With ``--slid``, every pair adds the truth slid 2.5-6 tolerances along its least pinned direction (:func:`slid_pose`):
a wrong pose that a scene's free direction (a corridor, a highway, a garage's yaw) hides. Not in the shipped fit (see
:data:`MIN_PINNED`).
With ``--low-pairs``, pairs of :data:`LOW_RIGS` made low-overlap (each scan cut to a sector of azimuth, the source's
turned from the target's, so that the target can judge 10-40 % of the source at the truth) add the same poses and the
truth moved within 0.5 deg / 0.1 m (GICP rarely finds the right pose there).

Real scans are rougher than simulated ones: most rigs are degraded (:func:`degrade`: range noise, things that
are in one scan only, the carrier's own body near the sensor) and half keep the motion skew of the sweep (not
compensated, as KITTI and nuScenes scans are not), so that the fit does not learn the simulator's clean surfaces.
A pose within 1 degree / 0.3 m of the truth is right; beyond 2 degrees or 0.5 m wrong; in between it is left out of
the fit. Each pose gives two feature rows (core/visibility.py): the network's sampled non-ground points ("pair", kept
for comparison) and a spread subset of the GICP voxels ("good_start": the model both verdicts of the registration
use). A logistic regression per row kind (classes weighted equally; the features of :data:`UNUSED` left out), and
one per row kind with the shares :data:`RELATIVE_SHARES` read over ``in_view`` (``_relative``: they judge the poses
the fit holds, :data:`HELD_BOUNDS`), are written to ``--out`` (``results/verdict_model.json`` in the working
directory unless told) with this command line and the floor on ``pinned`` (:data:`MIN_PINNED`, ``--min-pinned``);
the shipped file, ``deepbbs_ros/resources/verdict_model.json``, only with ``--out`` naming it and ``--force``. ::

    python scripts/calibrate_verdict.py --pairs 12         # fit as the shipped coefficients were (see below)
    python scripts/calibrate_verdict.py --dump rows.npz    # also keep the rows (the benchmark reads them)

The shipped file was fitted on 1123 poses; the same command collects 1095 with the current code (which has changed
since), and fits coefficients that accept more wrong simulated poses (docs/sensors.md): judge a
refit with ``scripts/benchmarks/verdict.py --model`` before writing it over the shipped file.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deepbbs_ros.config import Config, load_config  # noqa: E402
from deepbbs_ros.core import anchoring, calibrated, second_minimum, verdict, visibility, within  # noqa: E402
from deepbbs_ros.core.polish import correspondence_distance, finer_pair, finish  # noqa: E402
from deepbbs_ros.core.registration import DeepBBSRegistration, good_start_gicp, good_start_points  # noqa: E402
from deepbbs_ros.core.sweep_skew import check as check_skew  # noqa: E402
from deepbbs_ros.errors import RegistrationError  # noqa: E402
from deepbbs_ros.metrics import pair_errors  # noqa: E402
from deepbbs_ros.sim.patterns import driver_of  # noqa: E402
from deepbbs_ros.sim.rig import make_simulator  # noqa: E402
from deepbbs_ros.sim.trajectory import euler_to_matrix  # noqa: E402
from deepbbs_ros.sim.turned import turned_pair  # noqa: E402

#: (sensor, mount, place): every simulated sensor, every mount, every place
RIGS = (
    ("hdl64", "car", "urban"), ("hdl64", "car", "highway"), ("hdl32", "car", "suburban"), ("vlp16", "car", "open_road"),
    ("vlp16", "wheeled", "corridor"), ("ouster64", "car", "suburban"), ("os0_32", "wheeled", "hall"),
    ("os0_64", "legged", "courtyard"), ("os0_128", "wheeled", "garage"), ("os1_32", "legged", "corridor"),
    ("os1_64", "wheeled", "courtyard"), ("os1_128", "car", "urban"), ("xt32", "wheeled", "garage"),
    ("helios32", "car", "highway"), ("avia", "handheld", "courtyard"), ("avia", "handheld", "hall"),
    ("avia", "wheeled", "garage"), ("mid360", "legged", "hall"), ("mid360", "handheld", "corridor"),
    ("mid360", "wheeled", "urban"), ("vlp16", "handheld", "garage"), ("hdl32", "wheeled", "courtyard"),
    # sparse spinning sensors on a car at 2 Hz (nuScenes keyframes: 0.5-1 s, 1-5 m between scans)
    ("hdl32", "car", "urban", 2.0), ("vlp16", "car", "suburban", 2.0), ("os1_32", "car", "urban", 2.0),
    ("xt32", "car", "suburban", 2.0),
)
#: m; the skew check's points nearer than this are left out (the carrier's body), as the registration's (preprocess)
MIN_RANGE_SKEW = Config().preprocess.min_range
GAPS = (1, 3, 6, 10)  # frames between target and source (10 Hz; adding 20 made every refit worse on real scans)
GAPS_SLOW = (1, 2)  # frames between target and source of the rigs recorded at a lower rate
#: features left out of the fit (coefficient 0). plane_close reads a rough scene as a loose fit (right poses on real
#: nuScenes HDL-32E scans: median 0.72, simulated HDL-32E car pairs 0.88-0.95); plane_own (the same within the
#: target's own roughness) says it without that bias. The other ten are fitted: with ``pinned`` (how well the matches
#: on planes pin all six DOF) the wrong real Livox poses that slide along planes (pinned: median 0.020, right ones
#: 0.071) no longer look right, which kept plane_own, violations_nb and consistency_nb out before. Seed 38, 12 pairs,
#: no low-overlap pairs, judged end to end (benchmarks/verdict.py --model): right nuScenes poses rejected 8 / 10 -> 0/0
#: of 38, no real pose beyond 2 deg / 0.5 m accepted (highest p 0.043), right Livox poses rejected 1 / 4 -> 4 / 7;
#: offline on the same poses, all eleven: Livox 5 / 8; the seven fitted before plus pinned: Livox 10 / 14.
#: in_view and observable_rel (the overlap the pose expects, the measured one against it: core/visibility.py) are not
#: fitted. With observable_rel in observable's place (--unused plane_close observable in_view, seed 38, 12 pairs) right
#: real Livox poses rejected fall 4 / 7 -> 2 / 3 of 46 / 53 (pair / good start, end to end; no real pose beyond
#: 2 deg / 0.5 m accepted), but held-out low-overlap pairs have a wrong pose accepted (seed 39: 0 -> 1, an HDL-32E
#: sector slid 0.6 m, pinned 0.018; seed 40: 0 -> 1, an Avia in a corridor, pinned 0.002). With --min-pinned 0.02 as
#: well no more simulated wrong poses are accepted than with these coefficients (seeds 39 and 40, end to end), but
#: every right pose of a legged OS0-64 in a corridor is rejected (families.py --quick: 13 of 13; these: 0 of 14), and
#: right ones rejected rise on seed 40 (sparse 2 -> 6 of 57, turned 1 -> 7 of 35)
#: anchored and anchored_far (core/anchoring.py: the close matches lost when the pose moves along its weakest
#: direction) are not fitted either. Fitted (--seeds 38 41 42 --pairs 12 --turned-pairs 12 --drop-unheld 0.05 0.02
#: --unused plane_close in_view observable_rel anchored_far --min-pinned 0.02 --min-anchored-far 0.05), judged end to
#: end: right real Livox poses rejected 4 / 7 -> 0 / 0 of 46 / 53 (pair / good start; no real pose beyond
#: 2 deg / 0.5 m accepted, the most probable 0.47), but seed 40 accepts a Mid-360 corridor pose 2.02 deg off
#: (solid-state 0 -> 1) and a turned pair 90 deg off, and rejects more right turned poses (1 -> 5 of 34 / 33)
UNUSED: tuple[str, ...] = ("plane_close", "in_view", "observable_rel", "anchored", "anchored_far")
#: rigs whose pairs are made low-overlap (:func:`_low_overlap`: LOW_OVERLAP of the source judged at the truth, as on
#: real handheld Livox pairs, right poses down to 20 %, where the other rigs have no right pose under 36 %): each scan
#: cut to a sector of azimuth, the source's turned from the target's, as a narrow sensor turned between the scans.
#: Not in the shipped fit (--low-pairs 0): with them (--low-pairs 10, 291 poses, 96 right with observable 0.1-0.4)
#: every feature set tried accepted 4-5 real Livox poses beyond 2 deg / 0.5 m (up to 6.3 deg / 3.06 m, p up to 0.95),
#: with ``pinned`` too: its simulated right poses are pinned less than the real wrong ones (median 0.002 against
#: 0.020; their planar sectors leave a direction free), so the fit learns to ignore it (coefficient 2.1 -> 0.5)
#: Refitted later with them and the turned pairs (--pairs 12 --low-pairs 10 --turned-pairs 12, 1752 poses; judged
#: offline on verdict.py's seed 39 / 40 poses, good start): wrong accepted rise, low overlap 0 / 0 -> 9 / 8,
#: turned 0 / 1 -> 8 / 10; leaving out the right poses the fit neither pins nor anchors (--drop-unheld 0.02 0.1):
#: low overlap 0 / 0 -> 1 / 1, turned 0 / 1 -> 2 / 4, dense 1 / 0 -> 3 / 1, sparse 0 / 0 -> 1 / 3; leaving out the truth
#: moved by hand (kind "truth"): low overlap 0 / 0 -> 1 / 1, turned 0 / 1 -> 4 / 5, dense 1 / 0 -> 2 / 0, sparse
#: 0 / 0 -> 1 / 1, solid 0 / 0 -> 1 / 0.
#: The right low-overlap poses rejected are mostly that truth moved by hand, free along a direction (pinned median
#: 0.003), which no feature tells from a slide (docs/sensors.md)
LOW_RIGS = (
    ("avia", "handheld", "courtyard"), ("avia", "handheld", "hall"), ("avia", "legged", "garage"),
    ("avia", "handheld", "corridor"), ("mid360", "handheld", "corridor"), ("mid360", "legged", "courtyard"),
    ("mid360", "handheld", "hall"), ("vlp16", "handheld", "garage"), ("os1_32", "legged", "corridor"),
    ("hdl32", "wheeled", "courtyard"), ("avia", "wheeled", "hall"), ("avia", "wheeled", "corridor"),
)
LOW_OVERLAP = (0.10, 0.40)  # the observable share at the truth a low-overlap pair must have
#: rigs whose pairs are turned pairs (``--turned-pairs``; sim/turned.py: both scans cast from two poses of the walk,
#: 0.3-2.5 m and 8-50 degrees of heading apart, as real hand-held Livox keyframes are), narrow and 360-degree
#: solid-state sensors carried by hand or on legs, indoors and in courtyards; the poses: GICP's answers, the truth moved
#: beyond 2 deg / 0.5 m and the whole pipeline's answer (right, or a local minimum that fits like a real wrong Livox
#: pose: plane_own 0.91, pinned 0.011, medians). Not in the shipped fit: with them (--pairs 12 --turned-pairs 12, seed
#: 38) right real Livox poses rejected fell 4 / 7 -> 1 / 2 of 46 / 53 (pair / good start) with no real pose beyond
#: 2 deg / 0.5 m accepted, but simulated wrong poses accepted rose (seed 39: solid-state 1 -> 2, low-overlap 0 -> 1,
#: turned pairs 1 -> 6 of 83, mostly a Mid-360 slid 1.7-2.3 m along a corridor, pinned 0.008; benchmarks/verdict.py
#: --model, end to end)
TURNED_RIGS = (
    ("avia", "handheld", "courtyard"), ("avia", "handheld", "hall"), ("avia", "handheld", "corridor"),
    ("avia", "handheld", "garage"), ("avia", "legged", "courtyard"), ("mid360", "handheld", "corridor"),
    ("mid360", "handheld", "courtyard"), ("mid360", "legged", "garage"),
)
TURNED_OVERLAP = (0.10, 1.0)  # the observable share at the truth a turned pair must have (measured, not imposed)
PINNED = visibility.FEATURES.index("pinned")
HELD = visibility.FEATURES.index("anchored_far")
#: the shipped floor on ``pinned`` (core/calibrated.py ``min_pinned``; 0: none). 0.02 (a pose the fit leaves free by
#: more than about seven tolerances, 2 m / 7 degrees, along some direction is not accepted) rejects right poses in
#: corridors that nothing pins: see UNUSED. 0.5 with --min-anchored-far 0.02 (unsure: moved 1.5 m / 5 degrees along its
#: weakest direction either way, the pose keeps 98 % of its close points) accepts 0 / 2 of 178 / 180 truths slid along
#: that direction (--slid rows of seeds 39 / 40; shipped: 10 / 17) and seed 43's wrong poses fall 2 / 1 / 4 -> 1 / 1 / 2
#: (dense / solid / turned), but end to end (benchmarks/families.py --quick, that file in place of the shipped one) it
#: still accepts two Mid-360 legged garage answers 2.19 / 2.69 deg off and loses right ones along corridors (OS0-64
#: legged: 14 -> 12 of 14; real Livox walk 46 -> 45): not shipped. The slid rows in the fit (--slid --pairs 12) accept
#: 5 / 5 slid poses but low-overlap wrong ones 0 -> 3 of 95 (seed 39). With observable_rel for observable as well
#: (--unused plane_close observable in_view anchored anchored_far), end to end: right real Livox poses rejected
#: 4 / 7 -> 2 / 4 of 45-46 / 53 (no real pose beyond 2 deg / 0.5 m accepted, the most probable 0.13), but the same
#: garage and corridor figures, and offline a low-overlap wrong pose accepted (seed 39, p 0.88)
MIN_PINNED = 0.0
#: the shares the ``_relative`` models read over ``in_view`` (core/calibrated.py), and the bounds on ``pinned`` and
#: ``anchored_far`` from which they judge a pose (one the fit holds: free by at most seven tolerances, about 2 m or 7
#: degrees, or held 1.5 m / 5 degrees away by a tenth of its close points); below both, the plain models. A right
#: pose of a narrow sensor that turned keeps a small share of its source in the target's view: its fitness and
#: observable are low, its shares of what is in view high (real Livox walk, rejected right poses: in_view 0.27-0.59).
#: Seed 38, 12 pairs, judged end to end (benchmarks/verdict.py --model): right real Livox poses rejected 4 / 6 -> 1 / 2
#: of 48 / 51 (pair / good start), no real pose beyond 2 deg / 0.5 m accepted (highest p 0.43). For every pose
#: (--held 0 1) with a veto instead (--min-pinned 0.01 --min-anchored-far 0.1): a simulated low-overlap pose 0.6 m off
#: accepted (seed 39, pinned 0.018) and right corridor poses rejected (families.py --quick, OS0-64 legged corridor:
#: 0 -> 6 of 12)
RELATIVE_SHARES: tuple[str, ...] = ("fitness", "observable")
HELD_BOUNDS = (0.02, 0.1)
FAR = 40  # frames: "another place" (the other end of a loop, or far along a road)


def perturb(rng: np.random.Generator, yaw_deg: tuple[float, float], trans: tuple[float, float],
            tilt_deg: float = 1.0) -> np.ndarray:
    """A random rigid motion: yaw of magnitude in ``yaw_deg``, horizontal shift in ``trans`` m, small tilt."""
    yaw = np.radians(rng.uniform(*yaw_deg) * rng.choice([-1, 1]))
    roll, pitch = np.radians(rng.uniform(-tilt_deg, tilt_deg, 2))
    T = np.eye(4)
    T[:3, :3] = euler_to_matrix(roll, pitch, yaw)
    a = rng.uniform(0, 2 * np.pi)
    T[:3, 3] = rng.uniform(*trans) * np.array([np.cos(a), np.sin(a), 0.0])
    return T


def degrade(points: np.ndarray, rng: np.random.Generator, body: np.ndarray | None) -> np.ndarray:
    """A simulated scan (N, 3) made more like a real one: range noise (up to 12 cm: at 10 cm the target's own plane
    residuals, core/target_surface.py's ``self_residuals``, reach real scans': 90 % within 0.21-0.27 m on KITTI,
    nuScenes and the Livox walk, 0.11-0.20 m on clean simulated scans), 0-4 boxes seen in this scan
    only (cars and people that moved), and ``body`` (K, 3), the carrier's own points, fixed to the sensor."""
    p = np.asarray(points, np.float64)
    r = np.linalg.norm(p, axis=1, keepdims=True)
    p = p * (1 + rng.normal(0, rng.uniform(0.005, 0.12), (len(p), 1)) / np.maximum(r, 0.1))
    extra = [] if body is None else [body]
    for _ in range(int(rng.integers(0, 5))):
        a = rng.uniform(-np.pi, np.pi)
        c = rng.uniform(3, 25) * np.array([np.cos(a), np.sin(a), 0.0])
        size = rng.uniform([0.5, 0.5, 0.8], [4.5, 2.0, 2.0])
        n = int(rng.integers(50, 400))
        q = rng.uniform(-0.5, 0.5, (n, 3)) * size
        face = rng.integers(0, 3, n)
        q[np.arange(n), face] = np.sign(q[np.arange(n), face]) * size[face] / 2  # on the box's faces
        extra.append(q + c + np.r_[0, 0, np.min(p[:, 2]) + size[2] / 2])
    return np.vstack([p, *extra]).astype(np.float32)


def body_points(rng: np.random.Generator) -> np.ndarray | None:
    """The carrier's own returns (a roof edge, a robot's frame, a hand) about 1.5-2.8 m round the sensor, or None."""
    if rng.random() < 0.4:
        return None
    n = int(rng.integers(100, 600))
    a = rng.uniform(-np.pi, np.pi) + rng.uniform(-1.2, 1.2, n)
    rad = rng.uniform(1.5, 2.8, n)
    return np.c_[rad * np.cos(a), rad * np.sin(a), rng.uniform(-1.0, -0.2, n)]


def rows_of(src, tgt, T: np.ndarray, rc) -> tuple[np.ndarray, np.ndarray]:
    """The pair verdict's and the good start's feature rows of the pose ``T`` (src and tgt PreprocessResults)."""
    tpc = tgt.polish_cloud
    pair = visibility.pose_features(src.points, T, tpc, rc.verdict_dist)
    good = visibility.pose_features(good_start_points(src.polish_cloud, rc), T, tpc, rc.verdict_dist)
    return pair, good


def fine_rows(src, tgt, T: np.ndarray, rc) -> np.ndarray:
    """The good start's feature rows of the pose ``T`` judged on both scans' scene-sized grids
    (core/verdict.py :func:`on_scene_grid`): (2, F), at ``verdict_dist`` and at ``verdict_dist`` scaled with the finer
    grid (``registration.good_start_finish_grid`` "scene"); NaN where either scan has none."""
    out = np.full((2, len(visibility.FEATURES)), np.nan)
    grid = verdict.on_scene_grid(src.polish_cloud, tgt.polish_cloud, rc)
    if grid is None:
        return out
    pts, tf, d = grid
    out[0] = visibility.pose_features(pts, T, tf, rc.verdict_dist)
    out[1] = visibility.pose_features(pts, T, tf, d)
    return out


def label(T: np.ndarray, T_gt: np.ndarray) -> tuple[int, float, float]:
    """1 right (1 deg / 0.3 m), 0 wrong (beyond 2 deg or 0.5 m), -1 in between."""
    r, t = pair_errors(T, T_gt)
    r, t = float(r), float(t)
    return (1 if r <= 1.0 and t <= 0.3 else 0 if r > 2.0 or t > 0.5 else -1), r, t


class _Scans:
    """Scans of one simulated recording, prepared as the registration does (degraded first when ``rough``), each
    once: ``scans(k)`` -> (PreprocessResult, T_world_lidar)."""

    def __init__(self, sim, reg, driver: str, rng: np.random.Generator, body: np.ndarray | None, rough: bool):
        self.sim, self.reg, self.driver, self.rng, self.body, self.rough = sim, reg, driver, rng, body, rough
        self.cache: dict[int, tuple] = {}

    def __call__(self, k: int) -> tuple:
        if k not in self.cache:
            s = self.sim.scan_at(k)
            pts = degrade(s.points, self.rng, self.body) if self.rough else s.points
            self.cache[k] = (self.reg.preprocess(pts, *_times(s, len(pts)), driver=self.driver), s.T_world_lidar)
        return self.cache[k]

    def prepare(self, points: np.ndarray):
        """A scan's points (N, 3) prepared as the registration does (degraded first when ``rough``; not cached)."""
        return self.reg.preprocess(degrade(points, self.rng, self.body) if self.rough else points, driver=self.driver)

    def sector(self, k: int, center: float, width: float) -> tuple:
        """Scan ``k`` with only the returns within ``width`` degrees of azimuth round ``center`` (not cached)."""
        s = self.sim.scan_at(k)
        pts = degrade(s.points, self.rng, self.body) if self.rough else s.points
        off = (np.degrees(np.arctan2(pts[:, 1], pts[:, 0])) - center + 180.0) % 360.0 - 180.0
        keep = np.abs(off) <= width / 2
        times, stamp = _times(s, len(pts))
        return self.reg.preprocess(pts[keep], None if times is None else times[keep], stamp,
                                   driver=self.driver), s.T_world_lidar


def _times(scan, n: int) -> tuple[np.ndarray | None, int | None]:
    """(per-point times (n,) s, stamp) of a simulated ``scan`` (a raw sweep: the skew check's input) whose points were
    degraded into ``n`` (:func:`degrade` appends its extra points: spread over the sweep's times); (None, None) for a
    compensated sweep (no times)."""
    t = scan.point_times()
    if t is None:
        return None, None
    t = np.asarray(t, np.float64)
    return np.r_[t, np.linspace(t.min(), t.max(), n - len(t))], scan.stamp_ns


def slid_pose(T: np.ndarray, points: np.ndarray, target, dist: float, k: float) -> np.ndarray | None:
    """``T`` (4, 4) moved by ``k`` tolerances (core/anchoring.py's units: 0.3 m, 1 degree) along the direction the
    plane matches of ``points`` (source frame) under ``T`` pin least (``pinned``'s weakest direction, about the
    target's origin): the wrong pose a slide along the scene's free direction reaches; None without enough matches."""
    moved = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    tpts, _, _, normals, _ = visibility._target(target, dist)
    if normals is None or len(moved) == 0:
        return None
    idx, sq = target.tree.batch_nearest_neighbor_search(moved, num_threads=1)
    idx, sq = np.asarray(idx, np.int64), np.asarray(sq, np.float64)
    plane = np.einsum("ij,ij->i", moved - tpts[idx], normals[idx])
    m = (sq <= dist * dist) & (np.abs(plane) <= 0.2 * dist)
    twist = anchoring.weakest(moved[m], normals[idx[m]])
    if twist is None:
        return None
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = anchoring._rotation(k * twist[3:]), k * twist[:3]
    return S @ T


def _pair_rows(pair: tuple, far, rng: np.random.Generator, rc, out: dict, ri: int, truth: bool = False,
               reg=None, slid: bool = False, second: bool = False, scene: bool = False, starts=None) -> None:
    """Append to ``out`` the rows of the poses of one pair (``pair``: the target's and the source's (prepared scan,
    T_world_lidar); ``far()``: the same for a scan of another place; see the module). ``truth``: also the truth
    moved a little (within 0.5 deg / 0.1 m), a right pose where GICP may not find one; ``reg``: also the whole
    pipeline's answer from identity (``DeepBBSRegistration.register``), right or its own local minimum; ``slid``: also
    the truth slid along its weakest direction (:func:`slid_pose`), a wrong pose the scene's planes hardly tell;
    ``scene``: also the good start's rows on the scene-sized grids (``fine``: :func:`fine_rows`) and each GICP
    answer finished there (core/polish.py finish; ``fin``: its rows on GICP's grid and on the scene's with the scaled
    distance, ``fin_y``: its label, degrees, metres; ``fin_amb``: taken on the scene's grids, the second-minimum check
    there finds another minimum as good); NaN (False) where a scan has no finer grid or when off;
    ``second``: a pose the verdict takes (``verdict_probability``) is also checked for a second minimum as good along
    its weakest direction, as the registration's own verdict does (core/second_minimum.py; ``ambiguous``);
    ``starts``: ``starts(kind, src, tgt, T_start, T_gt, ri)`` on each near / far start instead of any row (the same
    draws: scripts/benchmarks/good_start_degenerate.py)."""
    (tgt, Tt), (src, Ts) = pair
    T_gt = np.linalg.inv(Tt) @ Ts
    t_gicp = time.perf_counter()
    ref = good_start_gicp(src.polish_cloud, tgt.polish_cloud, T_gt, rc)  # where GICP settles from the truth
    gicp_ms = (time.perf_counter() - t_gicp) * 1e3  # the pair's GICP (the skew check's cost is read against it)
    T_ref = ref.T_target_source if ref.applied else T_gt
    poses = []
    for kind, yaw, tr in (("near", (0, 3), (0, 0.5)), ("far", (10, 45), (1, 4)), ("far", (5, 30), (0.5, 3))):
        T0 = perturb(rng, yaw, tr) @ T_gt
        if starts is not None:
            starts(kind, src, tgt, T0, T_gt, ri)
            continue
        pol = good_start_gicp(src.polish_cloud, tgt.polish_cloud, T0, rc)
        if pol.applied:
            poses.append((kind, pol.T_target_source))
    poses.append(("moved", perturb(rng, (2, 15), (0.5, 2.5)) @ T_gt))
    poses.append(("moved", perturb(rng, (0, 2), (0.6, 1.5)) @ T_gt))
    if truth:
        poses.append(("truth", perturb(rng, (0, 0.5), (0, 0.1), 0.2) @ T_gt))
    if slid:  # the truth slid along the scene's least constrained direction by 2.5-6 tolerances, either way
        T_s = slid_pose(T_gt, good_start_points(src.polish_cloud, rc), tgt.polish_cloud, rc.verdict_dist,
                        rng.uniform(2.5, 6.0) * rng.choice([-1, 1]))
        if T_s is not None:
            poses.append(("slid", T_s))
    if reg is not None:
        poses.append(("pipeline", reg.register(src, tgt, preprocessed=True).T_target_source))
    other, To = far()
    if starts is not None:  # the draws are made: no row
        return
    if np.linalg.norm(To[:3, 3] - Tt[:3, 3]) > 8.0:  # another place: any answer is wrong
        pol = good_start_gicp(other.polish_cloud, tgt.polish_cloud, np.eye(4), rc)
        poses.append(("other", pol.T_target_source if pol.applied else np.eye(4)))
        T_other = np.linalg.inv(Tt) @ To
    for kind, T in poses:
        y, r, t = label(T, T_other if kind == "other" else T_gt)
        if y < 0:
            continue
        s_pre = other if kind == "other" else src
        pair, good = rows_of(s_pre, tgt, T, rc)
        near = kind != "other" and label(T, T_ref)[0] == 1
        ambiguous = bool(second and rc.second_minimum
                         and calibrated.probability(good[None], "good_start")[0] >= rc.verdict_probability
                         and second_minimum.check(good_start_points(s_pre.polish_cloud, rc), T, s_pre.polish_cloud,
                                                  tgt.polish_cloud, rc).ambiguous)
        rough = visibility.roughness(tgt.polish_cloud, rc.verdict_dist)  # the target's own (benchmark)
        cov = within.pose_covariance(s_pre.polish_cloud, tgt.polish_cloud, T, rc.polish_max_corr_dist)
        cov = np.full((6, 6), np.nan) if cov is None else cov  # the pose's (core/within.py; NaN: none)
        fine = fine_rows(s_pre, tgt, T, rc) if scene else np.full((2, len(visibility.FEATURES)), np.nan)
        fin, fin_y, fin_amb = np.full((2, len(visibility.FEATURES)), np.nan), np.full(3, np.nan), False
        fin_within = np.full(2, np.nan)  # P(within | covariance) of the finished pose on the scene's grids (weak: with
        # the spread along a weak direction), where taken there
        if kind in ("near", "far") and np.isfinite(fine[0, 0]):  # GICP's answer finished on the scene's grids
            f = finish(s_pre.polish_cloud, tgt.polish_cloud, T, rc)
            if f is not None and f.applied:
                fin_y[:] = label(f.T_target_source, T_gt)
                fin[0] = rows_of(s_pre, tgt, f.T_target_source, rc)[1]
                fin[1] = fine_rows(s_pre, tgt, f.T_target_source, rc)[1]
                if calibrated.probability(fin[1], "good_start") >= rc.good_start_probability:  # taken: a 2nd minimum?
                    pts, tf, d = verdict.on_scene_grid(s_pre.polish_cloud, tgt.polish_cloud, rc)
                    fin_amb = second_minimum.check(pts, f.T_target_source, s_pre.polish_cloud.finer(), tf,
                                                   dataclasses.replace(rc, verdict_dist=d)).ambiguous
                    fin_within = np.array([_within_on_scene_grid(s_pre.polish_cloud, tgt.polish_cloud,
                                                                 f.T_target_source, rc, w) for w in (False, True)])
        grid = (s_pre.polish_cloud.fine_voxel, tgt.polish_cloud.fine_voxel)
        sk = check_skew(s_pre, tgt, T, rc, MIN_RANGE_SKEW)  # scans with per-point times only (raw sweeps)
        skew = np.full(8, np.nan) if sk is None else np.array(
            [sk.rot_deg, sk.trans_m, sk.rot_est_deg, sk.trans_est_m, sk.rot_se_deg, sk.trans_se_m, sk.ms, gicp_ms])
        for k, v in (("skew", skew), ("pair", pair), ("good", good), ("fine", fine), ("grid", grid), ("fin", fin),
                     ("fin_y", fin_y), ("fin_amb", fin_amb), ("fin_within", fin_within),
                     ("y", y), ("rot", r), ("trans", t), ("rig", ri),
                     ("kind", kind), ("near_ref", near), ("rough", rough[0]), ("self_plane", rough[1]),
                     ("ambiguous", ambiguous), ("cov", cov)):
            out[k].append(v)


def _within_on_scene_grid(source, target, T: np.ndarray, rc, weak: bool) -> float:
    """P(within the tolerance | the covariance) (core/within.py) of the pose ``T`` (4, 4) finished on the scans'
    scene-sized grids, on those grids (the precision stage's clouds' ``finer()``), paired within GICP's correspondence
    distance there (core/polish.py correspondence_distance); ``weak``: with the spread along a weak direction. 0
    where either has no finer grid. verdict.py's ``good_start_scene_grid`` ``scene_within*`` columns (tried, not
    shipped: docs/sensors.md)."""
    fine = finer_pair(source, target)
    if fine is None:
        return 0.0
    cov = within.pose_covariance(*fine, T, correspondence_distance(fine, rc), 1, weak)
    return within.probability(cov, rc.success_trans, rc.success_rot_deg)


def _low_overlap(scan, i: int, j: int, rng: np.random.Generator, rc) -> tuple | None:
    """Scans ``i`` and ``j`` as a narrow sensor turned between them would see them: each only a sector of azimuth,
    the source's turned from the target's so that the share of the source the target can judge at the truth
    (``observable``) is within :data:`LOW_OVERLAP` (up to 4 draws); None if no draw is."""
    obs = visibility.FEATURES.index("observable")
    fov = 70.0 if scan.driver == driver_of("avia") else 360.0
    for _ in range(4):
        width = rng.uniform(0.45, 0.6) * fov if fov < 360 else rng.uniform(70.0, 130.0)
        turn = rng.uniform(0.6, 0.9) * width * rng.choice([-1, 1])
        try:
            tgt, Tt = scan.sector(i, 0.0, width)
            src, Ts = scan.sector(j, turn, width)
        except RegistrationError:  # a sector of floor only
            continue
        f = visibility.pose_features(good_start_points(src.polish_cloud, rc), np.linalg.inv(Tt) @ Ts,
                                     tgt.polish_cloud, rc.verdict_dist)
        if LOW_OVERLAP[0] <= f[obs] <= LOW_OVERLAP[1]:
            return (tgt, Tt), (src, Ts)
    return None


def _turned(scan, i: int, rng: np.random.Generator, rc) -> tuple | None:
    """A turned pair from frame ``i`` (sim/turned.py) prepared as the registration does, whose observable share at
    the truth is within :data:`TURNED_OVERLAP` (up to 4 draws); None if no draw is."""
    obs = visibility.FEATURES.index("observable")
    for _ in range(4):
        tp = turned_pair(scan.sim, i, rng)
        if tp is None:
            continue
        try:
            tgt, src = scan.prepare(tp.target.points), scan.prepare(tp.source.points)
        except RegistrationError:  # a scan of floor only
            continue
        f = visibility.pose_features(good_start_points(src.polish_cloud, rc), tp.T_target_source, tgt.polish_cloud,
                                     rc.verdict_dist)
        if TURNED_OVERLAP[0] <= f[obs] <= TURNED_OVERLAP[1]:
            return (tgt, tp.target.T_world_lidar), (src, tp.source.T_world_lidar)
    return None


def collect(rigs, seed: int, pairs: int, frames: int = 60, log=print, low: bool = False,
            rig0: int = 0, turned: bool = False, slid: bool = False,
            config: Config | None = None, second: bool = False, scene: bool = False,
            starts=None) -> dict[str, np.ndarray]:
    """Feature rows of poses on simulated pairs (see the module): {"pair", "good", "y", "rot", "trans", "rig",
    "kind", "near_ref", "rough", "self_plane", "ambiguous"} (``rough``, ``self_plane``: the target's
    :func:`visibility.roughness`;
    ``near_ref``: within 1 deg / 0.3 m of GICP started at the truth, where the pattern lets GICP
    settle; the fit does not use it). ``low``: low-overlap pairs (:func:`_low_overlap`); ``turned``: turned pairs
    (:func:`_turned`, over 100 frames); ``slid``: the truth slid along its weakest direction too; ``rig0``: the
    index of the first rig (its ``rig`` rows, its simulator's seed); ``config``: the registration's (default: the
    defaults); ``second``: the second-minimum check on the poses the verdict takes (``ambiguous``, see
    :func:`_pair_rows`); ``scene``: the rows on the scene-sized grids too (``fine``, ``fin``, ``fin_y``: see
    :func:`_pair_rows`; ``grid``: both scans' finer grids, m, 0 for none, always); ``starts``: see :func:`_pair_rows`
    (no rows then)."""
    frames = 100 if turned else frames  # a hand-held walk takes 2.5 m in up to 50 frames
    reg = DeepBBSRegistration(config or Config())
    rc = reg.config.registration
    out = {k: [] for k in ("skew", "pair", "good", "y", "rot", "trans", "rig", "kind", "near_ref", "rough",
                           "self_plane", "ambiguous", "cov", "fine", "grid", "fin", "fin_y", "fin_amb", "fin_within")}
    rng = np.random.default_rng(seed if rig0 == 0 else [seed, rig0])
    for ri, (sensor, mount, place, *rate) in enumerate(rigs, rig0):
        t0 = time.perf_counter()
        # real scans are rarely motion-compensated (KITTI, nuScenes are not): half the rigs keep the sweep's skew
        skewed = rng.random() < 0.5
        sim = make_simulator(place, seed * 100 + ri, sensor, mount, frames=frames, compensate=not skewed,
                             rate_hz=rate[0] if rate else 10.0)
        gaps = GAPS_SLOW if rate else GAPS
        rough = rng.random() < 0.6  # most rigs degraded like a real recording (:func:`degrade`)
        scan = _Scans(sim, reg, driver_of(sensor), rng, body_points(rng) if rough else None, rough)

        for p in range(pairs):
            i = int(rng.integers(0, frames - FAR - 1))
            j = i + gaps[p % len(gaps)]
            pair = _low_overlap(scan, i, j, rng, rc) if low else _turned(scan, i, rng, rc) if turned else \
                (scan(i), scan(j))
            if pair is not None:
                _pair_rows(pair, partial(scan, min(frames - 1, i + FAR)), rng, rc, out, ri, truth=low,
                           reg=reg if turned and starts is None else None, slid=slid, second=second, scene=scene,
                           starts=starts)
        n = sum(1 for r in out["rig"] if r == ri)
        log(f"{sensor}/{mount}/{place}{' degraded' if rough else ''}{' skewed' if skewed else ''}: {n} poses, "
            f"{time.perf_counter() - t0:.1f} s")
    return {k: np.asarray(v) for k, v in out.items()}


def fit_logistic(X: np.ndarray, y: np.ndarray, l2: float = 1e-3,
                 unused: tuple[str, ...] = ()) -> tuple[np.ndarray, float]:
    """Logistic regression of y on X (rows of :func:`calibrated.design`), the two classes weighted equally; the
    features named in ``unused`` get coefficient 0."""
    if unused:
        keep = [i for i, f in enumerate(visibility.FEATURES) if f not in unused]
        coef, icpt = fit_logistic(X[:, keep], y, l2)
        full = np.zeros(X.shape[1])
        full[keep] = coef
        return full, icpt
    w = np.where(y == 1, 0.5 / max(np.sum(y == 1), 1), 0.5 / max(np.sum(y == 0), 1))

    def loss(beta):
        z = X @ beta[1:] + beta[0]
        p = 1.0 / (1.0 + np.exp(-z))
        nll = np.sum(w * (np.logaddexp(0, z) - y * z))
        g = X.T @ (w * (p - y))
        return nll + l2 * beta[1:] @ beta[1:], np.r_[np.sum(w * (p - y)), g + 2 * l2 * beta[1:]]

    res = minimize(loss, np.zeros(X.shape[1] + 1), jac=True, method="L-BFGS-B")
    return res.x[1:], float(res.x[0])


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import _fit_output

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=6, help="pairs per rig (default 6)")
    ap.add_argument("--seed", type=int, default=38)
    ap.add_argument("--config", type=Path, help="config YAML of the registration whose clouds the poses are scored on "
                    "(default: the defaults)")
    _fit_output.add_out(ap, "verdict_model.json", calibrated.DEFAULT_PATH)
    ap.add_argument("--dump", type=Path, help="also write the feature rows here (.npz)")
    ap.add_argument("--low-pairs", type=int, default=0,
                    help="low-overlap pairs per rig of LOW_RIGS (default 0: see LOW_RIGS)")
    ap.add_argument("--turned-pairs", type=int, default=0,
                    help="turned pairs per rig of TURNED_RIGS (a sensor turned and moved between its scans; default 0)")
    ap.add_argument("--slid", action="store_true",
                    help="also the truth slid 2.5-6 tolerances along its least constrained direction (wrong poses)")
    ap.add_argument("--rows", type=Path, nargs="+", help="fit on these rows (--dumps, joined) instead of simulating")
    ap.add_argument("--min-pinned", type=float, default=MIN_PINNED,
                    help=f"probability 0 for a pose pinned less than this (core/calibrated.py; default {MIN_PINNED})")
    ap.add_argument("--min-anchored-far", type=float, default=1.0,
                    help="the floor on pinned applies only to poses whose anchored_far is under this (default 1: all)")
    ap.add_argument("--seeds", type=int, nargs="+", help="simulate with each of these seeds, joined (not --seed)")
    ap.add_argument("--drop-unheld", type=float, nargs=2, metavar=("PINNED", "ANCHORED_FAR"),
                    help="leave out of the fit the right poses with pinned and anchored_far both under these: right "
                         "by luck (the fit neither pins nor anchors them), which would teach it to forgive a slide")
    ap.add_argument("--relative", nargs="*", default=list(RELATIVE_SHARES), choices=calibrated.RELATIVE,
                    metavar="FEATURE", help="also fit the _relative models, which read these shares over in_view, the "
                    f"overlap the pose expects (core/calibrated.py; default: {' '.join(RELATIVE_SHARES)}; none: no "
                    "_relative models)")
    ap.add_argument("--held", type=float, nargs=2, default=HELD_BOUNDS, metavar=("PINNED", "ANCHORED_FAR"),
                    help="the _relative models judge only poses with pinned or anchored_far at least these (default "
                         f"{HELD_BOUNDS[0]} {HELD_BOUNDS[1]}; 0 1: all)")
    ap.add_argument("--unused", nargs="*", default=list(UNUSED), choices=visibility.FEATURES, metavar="FEATURE",
                    help=f"features left out of the fit (default: {' '.join(UNUSED) or 'none'})")
    args = ap.parse_args(argv)
    _fit_output.check_out(ap, args)
    config = load_config(args.config) if args.config else None
    if args.rows:
        parts = [dict(np.load(f, allow_pickle=False)) for f in args.rows]
    else:
        parts = []
        for seed in args.seeds or [args.seed]:
            parts.append(collect(RIGS, seed, args.pairs, slid=args.slid, config=config))
            if args.low_pairs:
                parts.append(collect(LOW_RIGS, seed, args.low_pairs, low=True, rig0=len(RIGS), slid=args.slid,
                                     config=config))
            if args.turned_pairs:
                parts.append(collect(TURNED_RIGS, seed, args.turned_pairs, turned=True,
                                     rig0=len(RIGS) + len(LOW_RIGS), slid=args.slid, config=config))
    data = {k: np.concatenate([d[k] for d in parts if len(d["y"])]) for k in parts[0]}
    if args.dump:
        np.savez(args.dump, **data)
    if args.drop_unheld:
        g = data["good"]
        keep = ~((data["y"] == 1) & (g[:, PINNED] < args.drop_unheld[0]) & (g[:, HELD] < args.drop_unheld[1]))
        data = {k: v[keep] for k, v in data.items()}
    models = {}
    kinds = (("pair", "pair", ()), ("good_start", "good", ()))
    if args.relative:
        kinds += (("pair_relative", "pair", args.relative), ("good_start_relative", "good", args.relative))
    for name, key, shares in kinds:
        X, y = calibrated.design(calibrated.relative(data[key], shares)), data["y"].astype(float)
        coef, icpt = fit_logistic(X, y, unused=tuple(args.unused))
        loose = (data[key][:, PINNED] < args.min_pinned) & (data[key][:, HELD] < args.min_anchored_far)
        p = np.where(loose, 0.0, 1.0 / (1.0 + np.exp(-(X @ coef + icpt))))
        models[name] = {"coef": [round(float(c), 6) for c in coef], "intercept": round(icpt, 6)}
        print(f"{name}: {int(y.sum())} right, {int((1 - y).sum())} wrong; highest wrong p {p[y == 0].max():.3f}, "
              f"right under 0.5: {int(np.sum(p[y == 1] < 0.5))} (each pose by this model)")
    doc = {"features": list(visibility.FEATURES), "transform": calibrated.TRANSFORM, "models": models,
           **({"relative": {"shares": list(args.relative), "held_pinned": args.held[0],
                            "held_anchored_far": args.held[1]}} if args.relative else {}),
           **({"min_pinned": args.min_pinned} if args.min_pinned else {}),
           **({"min_anchored_far": args.min_anchored_far} if args.min_pinned and args.min_anchored_far < 1 else {}),
           "fitted_on": f"{len(data['y'])} simulated poses, {len(np.unique(data['rig']))} rigs (sensor/mount/place), "
                        f"seed {' '.join(map(str, args.seeds or [args.seed]))}",
           "command": "python scripts/calibrate_verdict.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    _fit_output.write(args.out, json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
