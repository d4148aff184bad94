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

No ROS import here.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.errors import RegistrationError
from deepbbs_ros.reprs import short_repr, short_value

MIN_POINTS = 3  # fewer valid (or non-ground) points than this cannot be registered
_FIT_SAMPLES = 4096  # the ground plane is fitted on at most this many points near the sensor
_FIT_TOL = 0.25  # m; widest inlier band of the ground-plane fit
_MIN_SUPPORT = 0.10  # a RANSAC ground plane must hold this fraction of the points near the sensor


def deskew(points: np.ndarray, times: np.ndarray, delta: np.ndarray, period: float) -> np.ndarray:
    """Motion compensation to the scan stamp under constant velocity.

    Args:
        points: (N, 3) xyz, each in the sensor frame at its own time, metres.
        times: (N,) seconds since the scan stamp (negative before it).
        delta: (4, 4) a motion ``T_{a}_{b}`` of the sensor over ``period`` seconds (b later than a when
            ``period`` > 0), e.g. the last odometry step ``T_{k-1}_k``: the constant body twist is
            ``log(delta) / period``.
    Returns:
        (N, 3) float64: ``p_stamp = T_stamp_t p`` with ``T_stamp_t = exp(t / period * log delta)``;
        rotation exact (Rodrigues per point), translation to first order in the rotation.
    """
    from scipy.spatial.transform import Rotation

    w = Rotation.from_matrix(delta[:3, :3]).as_rotvec() / period  # rad/s
    v = delta[:3, 3] / period  # m/s
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    out = np.empty((len(p), 3))
    speed = float(np.linalg.norm(w))
    if speed < 1e-12:
        for i in range(3):
            out[:, i] = p[:, i] + t * v[i]
        return out
    # Rodrigues column by column (no (N, 3) temporaries, no np.cross): 2.5x faster on a 120k-point scan, same numbers
    kx, ky, kz = w / speed
    th = t * speed
    c, s = np.cos(th), np.sin(th)
    akdp = (1.0 - c) * (x * kx + y * ky + z * kz)
    out[:, 0] = c * x + s * (ky * z - kz * y) + akdp * kx + t * v[0]
    out[:, 1] = c * y + s * (kz * x - kx * z) + akdp * ky + t * v[1]
    out[:, 2] = c * z + s * (kx * y - ky * x) + akdp * kz + t * v[2]
    return out


@dataclass(frozen=True)
class SweepTimes:
    """The time at which a spinning LiDAR measures each azimuth: ``t = t_min + ((direction (az0 - az))
    mod 2 pi) / (2 pi) * period`` (az = atan2(y, x) in the sensor frame). It gives per-point times to
    points that lost theirs, e.g. the voxel centroids of the precision stage's clouds."""

    az0: float  # rad, azimuth measured first
    direction: int  # +1 clockwise seen from above (Velodyne), -1 counter-clockwise
    t_min: float  # s since the stamp
    period: float  # s per revolution

    MAX_POINTS = 20000  # points used by the fit (an even subsample)

    @classmethod
    def fit(cls, points: np.ndarray, times: np.ndarray) -> SweepTimes | None:
        """Fit to a scan (N, 3) with per-point ``times`` (N,) s; None when the times do not follow the
        azimuth (median residual above 2 % of the sweep: not a spinning sensor, or a scrambled field)."""
        step = max(1, len(points) // cls.MAX_POINTS)
        p = np.asarray(points[::step], dtype=np.float64)
        t = np.asarray(times[::step], dtype=np.float64)
        ok = np.isfinite(p).all(axis=1) & np.isfinite(t) & ((p[:, 0] ** 2 + p[:, 1] ** 2) > 1e-6)
        p, t = p[ok], t[ok]
        if len(t) < 100 or np.ptp(t) <= 0:
            return None
        az = np.arctan2(p[:, 1], p[:, 0])
        t_min, span = float(t.min()), float(np.ptp(t))
        first = t <= t_min + 0.005 * span
        az0 = float(np.angle(np.mean(np.exp(1j * az[first]))))
        best = None
        for direction in (1, -1):
            model = cls(az0, direction, t_min, span)
            res = float(np.median(np.abs(model(p) - t)))
            if best is None or res < best[0]:
                best = (res, model)
        return best[1] if best[0] <= 0.02 * span else None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64 times of the points (N, 3) from their azimuths."""
        az = np.arctan2(points[:, 1], points[:, 0])
        return self.t_min + np.mod(self.direction * (self.az0 - az), 2 * np.pi) / (2 * np.pi) * self.period


@dataclass
class PreprocessResult:
    """The output of :func:`preprocess`.

    Attributes:
        points: (M, 3) float32 sampled non-ground points, sensor frame, metres (M = num_points).
        ground_plane: (4,) float64 ``[a, b, c, d]`` with ``a x + b y + c z + d = 0``, unit normal,
            ``c > 0`` (upright fit) or turned towards the sensor (floor search: ``d`` is the sensor's height);
            None when ground removal is disabled or found no ground (every point kept).
        ground_status: how the ground was found: "upright" (the upright fit), "floor_search" (the floor search at
            any tilt), "none" (no plausible floor: every point kept) or "off" (``remove_ground`` false).
        sensor: the ``preprocess.sensor`` whose defaults were applied ("auto": none, the generic defaults).
        n_input: points given (including invalid ones).
        n_valid: finite points inside the range crop.
        n_nonground: valid points left after ground removal (before voxelisation and sampling).
        n_voxels: points after voxelisation (the FPS candidates).
        timings_ms: wall time per step (``valid_crop``, ``ground``, ``voxel``, ``fps``, ``total``;
            the dense subset is in ``total`` only).
        dense_points: (K, 3) float32 voxelised non-ground points, sensor frame, metres: every voxel
            centroid, or a seeded random subset of ``cfg.dense_max_points`` of them (the input of the
            final dense refinement, ``registration.dense_refine``); None when built by hand without it.
        polish_cloud: the whole cropped scan (ground kept) prepared for the GICP precision stage
            (``core.polish.PolishCloud``: voxel grid, k-d tree, covariances), set by
            ``DeepBBSRegistration.preprocess`` when ``registration.polish`` is on; None otherwise.
        raw_points, times, stamp_ns: the raw scan (N, 3) float32, its per-point times (N,) float64 (s
            since ``stamp_ns``) and its stamp, kept by ``DeepBBSRegistration.preprocess`` for deskewing
            when the scan has per-point times (``preprocess.deskew``); None otherwise.
        deskew: "deskewed" once ``DeepBBSRegistration.deskew_scan`` built ``deskewed_cloud``, else why not
            (``core.deskew.StreamDeskew``); "" when nothing was tried.
        deskewed_cloud, velocity: ``polish_cloud`` deskewed to the stamp with the scan's own velocity
            ``velocity`` = (``T_prev_cur`` (4, 4), seconds); the registration uses it when both scans have
            one and both velocities agree with the pair's own motion (``registration._deskew``).
    """

    points: np.ndarray
    ground_plane: np.ndarray | None
    n_input: int
    n_valid: int
    n_nonground: int
    n_voxels: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    dense_points: np.ndarray | None = None
    polish_cloud: Any = None
    raw_points: np.ndarray | None = None
    times: np.ndarray | None = None
    stamp_ns: int | None = None
    deskew: str = ""
    deskewed_cloud: Any = None
    velocity: tuple[np.ndarray, float] | None = None
    ground_status: str = ""
    sensor: str = "auto"
    # (cfg, seed) while the sampling waits (``prepare_scan(..., lazy=True)``: on the grid of ``polish_cloud``, put in
    # :func:`canonical_order`; (cfg, seed, raw scan (N, 3)) for a scan too sparse for that grid: on its own): the first
    # read of a sampled field (:data:`SAMPLED_FIELDS`) runs it; None once sampled
    pending_sample: Any = field(default=None, repr=False, compare=False)

    def __repr__(self) -> str:
        """One readable line (deepbbs_ros/reprs.py); a waiting sampling is shown as such, not run."""
        if self.sampled:
            return short_repr(self)
        parts = (f"{f.name}=" + ("<not sampled yet>" if f.name in SAMPLED_FIELDS
                                 else short_value(getattr(self, f.name))) for f in fields(self) if f.repr)
        return f"{type(self).__name__}({', '.join(parts)})"

    @property
    def ground_found(self) -> bool:
        """A ground plane was found and its layer removed (``ground_plane`` is set)."""
        return self.ground_plane is not None

    @property
    def sampled(self) -> bool:
        """The network's points are there (not waiting for their first use)."""
        return self.__dict__.get("pending_sample") is None

    def sample(self) -> PreprocessResult:
        """Run a waiting sampling (ground removal, FPS on the precision stage's grid, or on a sparse scan's own grid)
        now; no-op when done.
        Thread-safe (the node's registration thread and an input thread may both need it). Returns self."""
        if self.sampled:
            return self
        with _SAMPLE_LOCK:
            spec = self.__dict__.get("pending_sample")
            if spec is None:
                return self
            cfg, seed, *raw = spec
            t0 = time.perf_counter()
            d = self.__dict__
            if raw:  # a sparse scan: its own grid, from the raw scan, as prepare_scan would have sampled at once
                res = preprocess(raw[0], cfg, seed=seed)
                d["n_valid"] = res.n_valid
            else:
                grid = canonical_order(self.polish_cloud.points()).astype(np.float32)
                res = preprocess(grid, cfg, seed=seed, gridded=True)
            for name in SAMPLED_FIELDS:
                d["_" + name] = getattr(res, name)
            timings = dict(d.get("timings_ms") or {})
            for k, v in res.timings_ms.items():
                if k != "total":
                    timings[k] = v
            timings["sample"] = (time.perf_counter() - t0) * 1e3  # the grid's sort, ground removal, FPS
            timings["total"] = timings.get("total", 0.0) + timings["sample"]
            d["timings_ms"] = timings
            d["pending_sample"] = None
        return self


#: the fields of a :class:`PreprocessResult` that the (possibly waiting) sampling fills in: reading one runs it
SAMPLED_FIELDS = ("points", "ground_plane", "n_nonground", "n_voxels", "dense_points", "ground_status")
_SAMPLE_LOCK = threading.Lock()


def _sampled_field(name: str) -> property:
    key = "_" + name

    def get(self: PreprocessResult) -> Any:
        if self.__dict__.get("pending_sample") is not None:
            self.sample()
        return self.__dict__.get(key)

    def put(self: PreprocessResult, value: Any) -> None:
        self.__dict__[key] = value

    return property(get, put, doc=f"{name} (sampled on first read when the sampling waits)")


# installed after the dataclass is built: the fields keep their place in __init__, repr and replace, and a read
# of one of them runs a waiting sampling first
for _name in SAMPLED_FIELDS:
    setattr(PreprocessResult, _name, _sampled_field(_name))
del _name


# -- step 1: validity and range ------------------------------------------------------------------
def crop_range(points: np.ndarray, min_range: float, max_range: float) -> np.ndarray:
    """Mask of finite points with ``min_range <= ||p|| <= max_range``.

    Args:
        points: (N, 3) float xyz, metres; NaN/Inf rows are allowed (and never kept).
        min_range, max_range: metres, Euclidean distance from the sensor origin.

    Returns:
        (N,) bool mask.
    """
    pts = _as_points(points)
    with np.errstate(invalid="ignore", over="ignore"):
        r2 = np.einsum("ij,ij->i", pts, pts)
    # NaN compares False; Inf gives r2 = inf > max_range**2.
    return (r2 >= min_range * min_range) & (r2 <= max_range * max_range)


def crop_mask(points: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """(N,) bool mask of the points of ``points`` (N, 3) that step 1 keeps: :func:`crop_range` with the config's
    ranges, and outside ``cfg.self_filter_box`` ``[xmin, xmax, ymin, ymax, zmin, zmax]`` (sensor frame) when set."""
    keep = crop_range(points, cfg.min_range, cfg.max_range)
    box = cfg.self_filter_box
    if len(box) == 6:
        pts = _as_points(points)
        inside = np.ones(len(pts), dtype=bool)
        for axis in range(3):
            inside &= (pts[:, axis] >= box[2 * axis]) & (pts[:, axis] <= box[2 * axis + 1])
        keep &= ~inside
    return keep


# -- step 2: ground plane -------------------------------------------------------------------------
def fit_ground_plane(points: np.ndarray, cfg: PreprocessConfig, *, seed: int | None = None) -> np.ndarray:
    """Robust ground plane of a scan.

    Args:
        points: (N, 3) finite xyz, sensor frame, metres (z roughly up).
        cfg: uses ``ground_method``, ``ground_layer``, ``ground_seed_radius``,
            ``ground_max_tilt_deg`` and ``seed``.
        seed: overrides ``cfg.seed`` for the random steps (RANSAC triples, fit subsample).

    Returns:
        (4,) float64 ``[a, b, c, d]``, ``a x + b y + c z + d = 0``, ``||(a, b, c)|| = 1``, ``c > 0``.

    Raises:
        RegistrationError: fewer than 3 points within ``ground_seed_radius`` (horizontally), or no
            near-horizontal plane found.
    """
    pts = _as_points(points)
    rng = np.random.default_rng(cfg.seed if seed is None else seed)
    near_idx = np.flatnonzero(_r2_xy(pts) <= np.float32(cfg.ground_seed_radius**2))
    if len(near_idx) < MIN_POINTS:
        raise RegistrationError(
            f"ground fit: only {len(near_idx)} points within ground_seed_radius={cfg.ground_seed_radius} m "
            f"of the sensor (need {MIN_POINTS})"
        )
    if len(near_idx) > _FIT_SAMPLES:
        near_idx = np.sort(rng.choice(near_idx, _FIT_SAMPLES, replace=False))
    near = np.take(pts, near_idx, axis=0).astype(np.float64)
    min_nz = float(np.cos(np.deg2rad(cfg.ground_max_tilt_deg)))
    # Inlier band of the fit: the removed half-layer, but never wider than _FIT_TOL so that a
    # thick removal layer does not let wall bottoms into the fit.
    tol = min(cfg.ground_layer / 2.0, _FIT_TOL)
    if cfg.ground_method == "ransac":
        plane = _ransac_plane(near, tol, min_nz, cfg.ground_ransac_iters, rng)
    else:
        plane = _seeded_plane(near, tol, min_nz, cfg.ground_seed_radius)
    # Least-squares refinement on the points close to the robust estimate, tightening the band.
    for band in (tol, 0.5 * tol):
        cand = _refit_plane(near, plane, band, min_nz)
        if cand is None:
            break
        plane = cand
    return plane


def remove_ground(
    points: np.ndarray, cfg: PreprocessConfig, *, seed: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Fit the ground plane and mark the points outside its layer.

    Args:
        points: (N, 3) finite xyz, sensor frame, metres.
        cfg: see :func:`fit_ground_plane`; the removed layer is ``|signed distance| <= ground_layer / 2``.

    Returns:
        ``(nonground_mask (N,) bool, plane (4,) float64)``.
    """
    pts = _as_points(points)
    plane = fit_ground_plane(pts, cfg, seed=seed)
    dist = _signed_dist(pts, plane.astype(np.float32))
    return np.abs(dist) > cfg.ground_layer / 2.0, plane


def _lsq_plane(pts: np.ndarray) -> np.ndarray:
    """Total least-squares plane of (K, 3) float64 points: smallest principal axis, ``c >= 0``."""
    centroid = np.array([pts[:, 0].mean(), pts[:, 1].mean(), pts[:, 2].mean()])
    q = pts - centroid
    _, vecs = np.linalg.eigh(np.einsum("ki,kj->ij", q, q))
    normal = vecs[:, 0]
    if normal[2] < 0:
        normal = -normal
    return np.concatenate([normal, [-normal @ centroid]])


def _refit_plane(pts: np.ndarray, plane: np.ndarray, band: float, min_nz: float) -> np.ndarray | None:
    """Least-squares plane of the points of ``pts`` within ``band`` of ``plane``.

    None when fewer than MIN_POINTS are in the band or the fit tilts further than ``min_nz`` allows.
    """
    inl = np.compress(np.abs(_signed_dist(pts, plane)) <= band, pts, axis=0)
    if len(inl) < MIN_POINTS:
        return None
    cand = _lsq_plane(inl)
    return None if cand[2] < min_nz else cand


def _ransac_plane(pts: np.ndarray, tol: float, min_nz: float, iters: int, rng: np.random.Generator) -> np.ndarray:
    """Near-horizontal RANSAC plane (all hypotheses scored at once) of (K, 3) float64 points."""
    # Triples come from the lower half of the points (ground lies below most walls and poles);
    # hypotheses are scored on every other point, in float32.
    low = np.compress(pts[:, 2] <= np.median(pts[:, 2]), pts, axis=0)
    if len(low) < MIN_POINTS:
        low = pts
    tri = low[rng.integers(0, len(low), size=(iters, 3))]  # (H, 3 points, 3)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    normals[ok] /= norm[ok, None]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    ok &= normals[:, 2] >= min_nz
    if not ok.any():
        raise RegistrationError(
            f"ground fit: RANSAC found no plane within the allowed tilt of the horizontal among {len(pts)} points"
        )
    normals = normals[ok]
    d = -np.einsum("hj,hj->h", normals, tri[ok, 0])
    # Score: inliers within tol; ties broken towards the lower plane (smaller height offset d).
    sc = pts[::2].astype(np.float32)
    nf, df = normals.astype(np.float32), d.astype(np.float32)
    dist = sc[:, 0:1] * nf[:, 0] + sc[:, 1:2] * nf[:, 1] + sc[:, 2:3] * nf[:, 2] + df
    counts = np.count_nonzero(np.abs(dist) <= tol, axis=0)
    if counts.max() < _MIN_SUPPORT * len(sc):
        raise RegistrationError(
            f"ground fit: the best near-horizontal plane holds only {counts.max()} of {len(sc)} points "
            f"near the sensor (need {_MIN_SUPPORT:.0%})"
        )
    best = np.flatnonzero(counts == counts.max())
    best = best[np.argmax(d[best])]  # d = -height of the plane at the origin: largest d = lowest plane
    return np.concatenate([normals[best], [d[best]]])


def _seeded_plane(pts: np.ndarray, tol: float, min_nz: float, radius: float) -> np.ndarray:
    """Plane seeded by the dominant height near the sensor, grown outwards by least squares."""
    r2 = _r2_xy(pts)
    inner = np.compress(r2 <= (0.5 * radius) ** 2, pts, axis=0)
    if len(inner) < MIN_POINTS:
        inner = pts
    z = inner[:, 2]
    bin_w = max(tol / 2.0, 0.05)
    edges = np.arange(z.min(), z.max() + 2 * bin_w, bin_w)
    hist, edges = np.histogram(z, bins=edges)
    z0 = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    plane = np.array([0.0, 0.0, 1.0, -z0])
    for frac in (0.25, 0.5, 1.0):
        sel = np.compress(r2 <= (frac * radius) ** 2, pts, axis=0)
        for _ in range(2):
            cand = _refit_plane(sel, plane, 2.0 * tol, min_nz)
            if cand is None:
                break
            plane = cand
    return plane


# -- step 3: voxel grid ---------------------------------------------------------------------------
def voxel_downsample(points: np.ndarray, voxel_size: float) -> np.ndarray:
    """One point per occupied voxel: the centroid of the points in it.

    Voxels are the cubes ``floor(p / voxel_size)``. The output is ordered by voxel key, hence
    deterministic for a given input set.

    Args:
        points: (N, 3) finite xyz, metres.
        voxel_size: edge length in metres; ``<= 0`` returns the input unchanged (as float32).

    Returns:
        (M, 3) float32 centroids, M = number of occupied voxels.
    """
    pts = _as_points(points)
    if voxel_size <= 0 or len(pts) == 0:
        return pts
    # Pack the integer voxel coordinates into one int64 key, 21 bits per axis (no per-axis
    # reductions: those are slow on (N, 3) arrays).
    # int32 keys (10 bits per axis, faster to sort) when the cloud spans fewer than 1024 voxels.
    ijk = np.floor(pts * np.float32(1.0 / voxel_size))
    lo, hi = float(ijk.min()), float(ijk.max())
    if hi - lo >= 1 << 21:
        raise RegistrationError(
            f"voxel_downsample: cloud spans more than 2**21 voxels of {voxel_size} m along an axis"
        )
    bits, dtype = (10, np.int32) if hi - lo < 1 << 10 else (21, np.int64)
    ijk = (ijk - np.float32(lo)).astype(dtype)
    keys = (ijk[:, 0] << (2 * bits)) | (ijk[:, 1] << bits) | ijk[:, 2]
    order = np.argsort(keys)
    keys = keys[order]
    starts = np.flatnonzero(np.concatenate(([True], keys[1:] != keys[:-1])))
    sums = np.add.reduceat(np.take(pts, order, axis=0).astype(np.float64), starts, axis=0)
    counts = np.diff(np.append(starts, len(keys)))
    return (sums / counts[:, None]).astype(np.float32)


def canonical_order(points: np.ndarray) -> np.ndarray:
    """(N, 3) points sorted by x, then y, then z: the same array for the same set of points in any order.

    small_gicp's multi-threaded voxel grid returns its centroids in a run-dependent order; the random
    candidate subset and the start point of the sampling are index based, so a grid is put in this order
    first to keep the sampled points (and the registration) reproducible. One argsort on x, a full
    lexsort only when two x are equal.
    """
    pts = np.asarray(points)
    order = np.argsort(pts[:, 0], kind="stable")
    xs = pts[order, 0]
    if len(xs) > 1 and (xs[1:] == xs[:-1]).any():
        order = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0]))
    return np.take(pts, order, axis=0)


# -- step 4: farthest-point sampling --------------------------------------------------------------
def farthest_point_sample(points: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` farthest-point samples (bucket FPS of ``fpsample``).

    Deterministic for a given input and seed: the seed picks the start index. When the cloud has
    fewer than ``n`` points, the FPS order of all of them is repeated cyclically (each point appears
    ``floor(n / m)`` or ``ceil(n / m)`` times) so that the output always has ``n`` entries.

    Args:
        points: (M, 3) finite xyz, metres, M >= 1.
        n: number of samples, >= 1.
        seed: start-point seed.

    Returns:
        (n,) int64 indices into ``points``.
    """
    pts = _as_points(points)
    m = len(pts)
    if m == 0:
        raise RegistrationError("farthest_point_sample: empty point cloud")
    if n < 1:
        raise RegistrationError(f"farthest_point_sample: n must be >= 1, got {n}")
    k = min(n, m)
    start = int(np.random.default_rng(seed).integers(m))
    if m < 16:  # bucket FPS needs 2**h <= m; a plain FPS on a handful of points is instant
        idx = _fps_exact(pts, k, start)
    else:
        import fpsample

        # Tree height after the fpsample paper: bucket size 2**h, larger clouds want deeper trees.
        # (measured on LiDAR voxel clouds: h = 5 is fastest for 4k-8k points).
        h = int(np.clip(int(np.log2(m)) - 7, 3, 9))
        idx = fpsample.bucket_fps_kdline_sampling(pts, k, h, start_idx=start).astype(np.int64)
    if k < n:
        idx = np.resize(idx, n)  # cyclic repetition of the full FPS order
    return idx


def dense_subsample(points: np.ndarray, max_points: int, seed: int = 0) -> np.ndarray:
    """At most ``max_points`` of ``points`` as a seeded uniform random subset (order kept).

    Used on voxel centroids, which are already evenly spread: a random subset keeps that evenness at
    a fraction of the cost of farthest-point sampling.

    Args:
        points: (K, 3) float32 xyz, metres.
        max_points: cap; ``<= 0`` or ``>= K`` returns ``points`` unchanged.
        seed: subset seed.

    Returns:
        (min(K, max_points), 3) float32.
    """
    if max_points <= 0 or len(points) <= max_points:
        return points
    sub = np.random.default_rng([seed, 5150]).choice(len(points), max_points, replace=False)
    return np.take(points, np.sort(sub), axis=0)


def _fps_exact(pts: np.ndarray, k: int, start: int) -> np.ndarray:
    """Textbook O(k M) farthest-point sampling (used for tiny clouds)."""
    idx = np.empty(k, dtype=np.int64)
    idx[0] = start
    dist = np.sum((pts - pts[start]) ** 2, axis=1)
    for i in range(1, k):
        idx[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.sum((pts - pts[idx[i]]) ** 2, axis=1))
    return idx


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
    from deepbbs_ros.core.sensors import resolve

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
    from deepbbs_ros.core.ground import choose_floor, find_floor

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
    return np.abs(_signed_dist(pts, plane.astype(np.float32))) > cfg.ground_layer / 2.0, plane, status


def _need_points(n: int, reason: str) -> None:
    """RegistrationError ``preprocess: only {n} {reason}`` when fewer than MIN_POINTS points are left."""
    if n < MIN_POINTS:
        raise RegistrationError(f"preprocess: only {n} {reason}")


def _lap(timings: dict[str, float], name: str, since: float) -> float:
    """Record ``timings[name]`` = milliseconds since ``since`` (a perf_counter value); returns now."""
    now = time.perf_counter()
    timings[name] = (now - since) * 1e3
    return now


def _signed_dist(pts: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """(N,) signed distance of (N, 3) points to ``plane`` (4,) (column ops: no BLAS threads)."""
    return pts[:, 0] * plane[0] + pts[:, 1] * plane[1] + pts[:, 2] * plane[2] + plane[3]


def _r2_xy(pts: np.ndarray) -> np.ndarray:
    """(N,) squared horizontal distance from the sensor of (N, 3) points."""
    return pts[:, 0] * pts[:, 0] + pts[:, 1] * pts[:, 1]


def _as_points(points: np.ndarray) -> np.ndarray:
    """(N, 3) float32 view/copy of ``points``; RegistrationError otherwise (the shared check, core/points.py)."""
    return as_xyz(points, "preprocess")
