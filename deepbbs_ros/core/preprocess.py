"""Scan preprocessing: invalid-point removal, range crop, ground removal, voxel grid, FPS.

The pipeline turns one raw LiDAR sweep (``(N, 3)`` xyz in the sensor frame, metres, possibly with
NaN/Inf returns) into a fixed number of well spread non-ground points, the input of the DeepBBS
network:

0. ``sensor``: a named ``preprocess.sensor`` sets the defaults of that LiDAR (core/sensors.py); ``"auto"`` is
   resolved by the caller that knows the driver (``core.scans.prepare_scan``).
1. ``valid_crop``: drop non-finite points, keep ``min_range <= ||p|| <= max_range``, drop the points inside
   ``self_filter_box`` (the robot's body, a car's roof).
2. ``ground``: fit one ground plane ``a x + b y + c z + d = 0`` (unit normal, ``c > 0``) robustly
   on the points near the sensor and drop the layer ``|a x + b y + c z + d| <= ground_layer / 2``
   (DeepBBS removes a 0.5 m layer around a least-squares plane). Two robust seedings:

   * ``"ransac"``: planes through random point triples near the sensor, only near-horizontal ones
     (normal within ``ground_max_tilt_deg`` of +z), scored by their inlier count; the winner is
     refined by least squares on its inliers.
   * ``"seeded_lsq"``: the dominant height of the points near the sensor seeds a horizontal plane;
     least squares over the points close to the current plane is then repeated on growing radii,
     which follows a slope.

   A plain least-squares fit over the whole scan would be pulled up by buildings: both methods fit
   only points near the current plane estimate, and walls (vertical) never win a near-horizontal
   RANSAC hypothesis.

   That fit assumes a roughly upright sensor above the ground (a car roof). With ``ground_search`` "auto"
   (default) a plane it finds must also be a plausible floor (the sensor above it, few points under it:
   ``core.ground.plausible_floor``); when it finds none, the floor search at any tilt (``core.ground.find_floor``:
   handheld, tilted, low and indoor sensors) takes over, and when that finds none either, every point is kept
   (``ground_status`` says which happened). "upright" runs the first fit alone, "any" the floor search alone.
3. ``voxel``: one point per occupied ``voxel_size`` cube, the centroid of its points. A sparse cloud (fewer
   than ``min_candidates`` voxels from at least as many points) is put on a finer grid, ``voxel_size *
   sqrt(voxels / min_candidates)`` but at least ``voxel_size / 4`` (a scan's voxels fill surfaces: their count
   goes as 1 / voxel^2), so that about ``min_candidates`` candidates remain for the sampling. Skipped for
   ``gridded`` input: ``DeepBBSRegistration.preprocess`` (``preprocess.share_grid``, default) hands in
   the centroids of the precision stage's grid of the whole scan (``registration.polish_voxel``, put in
   :func:`canonical_order`), so a scan is voxelised once; steps 1, 2 and 4 then run on them.
4. ``fps``: farthest-point sampling (``fpsample`` bucket FPS) to ``num_points``, deterministic for a
   given seed. When fewer points remain, the FPS order of all of them is repeated cyclically
   (``idx[k] = order[k % m]``) so that every batch has exactly ``num_points`` points; each point
   then appears ``floor(n / m)`` or ``ceil(n / m)`` times.

5. ``dense``: the voxel centroids themselves (a seeded random subset of at most
   ``dense_max_points``) are kept as ``dense_points`` for the final dense refinement.

The steps live in their own modules: ``core/crop.py`` (1), ``core/ground_plane.py`` (2, the upright fit),
``core/sampling.py`` (3-5); the result is ``core/preprocess_result.py``, the sweep's per-point times and deskew
``core/sweep.py``. Their public names stay importable from here. No ROS import here.
"""

from __future__ import annotations

import time

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.crop import crop_mask, crop_range
from deepbbs_ros.core.ground import choose_floor, find_floor
from deepbbs_ros.core.ground_plane import MIN_POINTS, fit_ground_plane, remove_ground, signed_dist
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.preprocess_result import SAMPLED_FIELDS, PreprocessResult
from deepbbs_ros.core.sampling import canonical_order, dense_subsample, farthest_point_sample, voxel_downsample
from deepbbs_ros.core.sensors import resolve
from deepbbs_ros.core.sweep import SweepTimes, deskew
from deepbbs_ros.errors import RegistrationError

__all__ = [  # the public names, wherever they live
    "MIN_POINTS", "SAMPLED_FIELDS", "PreprocessResult", "SweepTimes", "canonical_order", "crop_mask", "crop_range",
    "deskew", "dense_subsample", "farthest_point_sample", "fit_ground_plane", "preprocess", "remove_ground",
    "voxel_downsample",
]


# -- the pipeline ---------------------------------------------------------------------------------
def preprocess(points: np.ndarray, cfg: PreprocessConfig | None = None, *, seed: int | None = None,
               gridded: bool = False) -> PreprocessResult:
    """Raw scan -> ``cfg.num_points`` non-ground points (see the module docstring for the steps).

    Args:
        points: (N, 3) float xyz in the sensor frame, metres; NaN/Inf rows are dropped.
        cfg: preprocessing parameters (defaults when None).
        seed: overrides ``cfg.seed`` (RANSAC, fit subsample, FPS start).
        gridded: ``points`` are already the voxel centroids of the whole scan (the precision stage's grid,
            ``preprocess.share_grid``): the voxel step is skipped, the crop, the ground removal and the
            sampling run on them.

    Returns:
        :class:`PreprocessResult` with ``points`` (num_points, 3) float32.

    Raises:
        RegistrationError: empty input, wrong shape, fewer than 3 finite points inside the range crop,
            or fewer than 3 points left after ground removal.
    """
    cfg = resolve(cfg or PreprocessConfig())
    seed = cfg.seed if seed is None else seed
    timings: dict[str, float] = {}
    t_start = t0 = time.perf_counter()

    pts = _as_points(points)
    n_input = len(pts)
    if n_input == 0:
        raise RegistrationError("preprocess: empty point cloud")

    # 1. finite points inside the range crop
    pts = np.compress(crop_mask(pts, cfg), pts, axis=0)
    n_valid = len(pts)
    _need_points(n_valid, f"of {n_input} points are finite and within [{cfg.min_range}, {cfg.max_range}] m "
                 f"(need {MIN_POINTS})")
    t1 = _lap(timings, "valid_crop", t0)

    # 2. ground plane and layer removal
    plane, status = None, "off"
    if cfg.remove_ground:
        keep, plane, status = _ground(pts, cfg, seed)
        if keep is not None:
            pts = np.compress(keep, pts, axis=0)
    n_nonground = len(pts)
    _need_points(n_nonground, f"of {n_valid} valid points are off the ground layer "
                 f"(ground_layer={cfg.ground_layer} m; need {MIN_POINTS})")
    t2 = _lap(timings, "ground", t1)

    # 3. voxel grid; keep the raw points when voxelising would leave fewer than num_points
    vox = pts if gridded else voxel_downsample(pts, cfg.voxel_size)
    if not gridded and cfg.voxel_size > 0 and len(vox) < cfg.min_candidates <= len(pts):
        # sparse cloud: a finer grid, about min_candidates voxels (their count goes as 1 / voxel^2)
        vox = voxel_downsample(pts, cfg.voxel_size * max(0.25, float(np.sqrt(len(vox) / cfg.min_candidates))))
    if len(vox) < cfg.num_points <= len(pts):
        vox = pts
    t3 = _lap(timings, "voxel", t2)

    # 4. farthest-point sampling to a fixed size
    cand = vox
    if 0 < cfg.fps_max_candidates < len(cand):
        # Bucket FPS cost grows with the candidates: a random subset of the (already uniform)
        # voxel centroids loses little coverage and bounds the time.
        sub = np.random.default_rng(seed).choice(len(cand), cfg.fps_max_candidates, replace=False)
        cand = np.take(cand, np.sort(sub), axis=0)
    idx = farthest_point_sample(cand, cfg.num_points, seed=seed)
    out = np.ascontiguousarray(np.take(cand, idx, axis=0), dtype=np.float32)
    _lap(timings, "fps", t3)

    # 5. the dense cloud of the final refinement: the voxel centroids, capped
    dense = np.ascontiguousarray(dense_subsample(vox, cfg.dense_max_points, seed=seed), dtype=np.float32)
    _lap(timings, "total", t_start)

    return PreprocessResult(
        points=out,
        ground_plane=plane,
        n_input=n_input,
        n_valid=n_valid,
        n_nonground=n_nonground,
        n_voxels=len(vox),
        timings_ms=timings,
        dense_points=dense,
        ground_status=status,
        sensor=cfg.sensor,
    )


def _ground(pts: np.ndarray, cfg: PreprocessConfig, seed: int) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Step 2: ``(nonground mask or None, plane or None, ground_status)`` of the valid points (see the module
    docstring: the upright fit, checked as a floor, then the floor search at any tilt)."""
    keep, upright = None, None
    if cfg.ground_search != "any":
        try:
            keep, upright = remove_ground(pts, cfg, seed=seed)
        except RegistrationError:
            pass  # no ground near the sensor (a cropped or indoor cloud)
        if cfg.ground_search == "upright":
            return (keep, upright, "upright") if upright is not None else (None, None, "none")
        plane, status = choose_floor(pts, upright, cfg, seed=seed)
    else:
        plane = find_floor(pts, cfg, seed=seed)
        status = "floor_search" if plane is not None else "none"
    if plane is None:
        return None, None, "none"
    if plane is upright:
        return keep, upright, status
    return np.abs(signed_dist(pts, plane.astype(np.float32))) > cfg.ground_layer / 2.0, plane, status


def _need_points(n: int, reason: str) -> None:
    """RegistrationError ``preprocess: only {n} {reason}`` when fewer than MIN_POINTS points are left."""
    if n < MIN_POINTS:
        raise RegistrationError(f"preprocess: only {n} {reason}")


def _lap(timings: dict[str, float], name: str, since: float) -> float:
    """Record ``timings[name]`` = milliseconds since ``since`` (a perf_counter value); returns now."""
    now = time.perf_counter()
    timings[name] = (now - since) * 1e3
    return now



def _as_points(points: np.ndarray) -> np.ndarray:
    """(N, 3) float32 view/copy of ``points``; RegistrationError otherwise (the shared check, core/points.py)."""
    return as_xyz(points, "preprocess")
