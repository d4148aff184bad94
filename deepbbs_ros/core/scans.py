"""A raw scan made ready for registration: everything ``DeepBBSRegistration.register`` needs of it (no ROS).

One :func:`prepare_scan` per scan (``DeepBBSRegistration.preprocess``): a scan prepared once serves as source
and as target (odometry, the node)::

    deskew      with a known motion of the sensor, the raw scan to its stamp (per-point times, core/deskew.py)
    polish      its precision-stage cloud: the whole cropped scan on the registration.polish_voxel grid, with
                k-d tree and covariances (core/polish.py; ``defer``: those two wait for PolishCloud.complete)
    sample      the network's points: crop, ground removal, farthest-point sampling (core/preprocess.py), on the
                centroids of that grid (preprocess.share_grid) or on their own grid

:func:`prepare_view` does the same for a part of a cloud prepared once (a map crop: core/localization.py), with no
precision-stage preparation of its own.

:func:`ready_to_judge` builds what the verdict reads of a prepared scan alone (its target tables), between a
stream's pairs. :func:`deskew_prepared` adds a prepared scan's precision-stage cloud deskewed with the scan's own
velocity, once its stream knows it (``core.deskew.StreamDeskew``). Points are (N, 3) metres in the sensor frame;
per-point times (N,) are seconds since the stamp.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.core.points import as_xyz
from deepbbs_ros.core.polish import (
    MIN_POLISH_POINTS,
    SMALL_GICP_TYPE,
    PolishCloud,
    PolishView,
    prepare_polish_cloud,
    prepared_cloud,
)
from deepbbs_ros.core.preprocess import PreprocessResult, SweepTimes, canonical_order, crop_mask, deskew, preprocess
from deepbbs_ros.core.sensors import guess_sensor, resolve
from deepbbs_ros.errors import RegistrationError

__all__ = ["prepare_scan", "prepare_view", "polish_cloud", "deskew_prepared", "ready_to_judge", "with_sensor"]


def prepare_scan(config: Config, points: np.ndarray, times: np.ndarray | None = None, stamp_ns: int | None = None,
                 motion: tuple[np.ndarray, float] | None = None, *, defer: bool = False,
                 threads: int = 1, lazy: bool = False, driver: str | None = None) -> PreprocessResult:
    """Raw scan (N, 3) metres -> :class:`PreprocessResult` (``config.preprocess``), with the scan's
    precision-stage cloud (``polish_cloud``) when ``registration.polish`` is on.

    With ``preprocess.share_grid`` (default) the network's points are sampled from the precision stage's voxel
    grid (``registration.polish_voxel``, whole cropped scan) instead of a second grid (``preprocess.voxel_size``
    on the non-ground points): one grid per scan, ~5 ms less per HDL-64 scan.

    Per-point ``times`` (N,) s since the stamp (Velodyne ``time``, Ouster ``t``), with ``preprocess.deskew`` on:
    with a known ``motion`` = (``T_a_b`` (4, 4), seconds from a to b) of the sensor (a stream's last step) the
    scan is deskewed to its stamp before anything else; without one the raw scan, its times and ``stamp_ns``
    are kept for :func:`deskew_prepared` once the scan's velocity is known. ``defer``: the precision-stage
    cloud's k-d tree and covariances wait (:meth:`PolishCloud.complete`); ``threads``: small_gicp's. ``lazy`` (with
    the shared grid): the network's points (ground removal, FPS) wait for their first read
    (:meth:`PreprocessResult.sample`): a registration from a good start (``register(..., good_start=True)``) needs
    only the precision-stage cloud, and pays for them only when it falls back to the deep passes.

    ``preprocess.sensor`` "auto" is settled here: by ``driver`` (``msg_adapters.layouts.recognise_driver`` of the
    scan's PointCloud2 fields, when the caller has them) or the scan's shape (``core.sensors.guess_sensor``); the
    defaults of that sensor apply to the whole preparation (``result.sensor`` names it).
    """
    points = as_xyz(points, "preprocess")  # (N, 3) real numbers, NaN rows dropped by the crop (core/points.py)
    config = with_sensor(config, points, driver)
    pp, rc = config.preprocess, config.registration
    keep_raw, deskew_ms = None, None
    if pp.deskew and times is not None:
        tt = np.asarray(times, dtype=np.float64).reshape(-1)
        if len(tt) != len(points):
            raise RegistrationError(f"deskew: {len(tt)} per-point times for {len(points)} points")
        if np.ptp(tt) > 0 and np.isfinite(tt).all():
            if motion is not None and abs(motion[1]) > 1e-6:
                t0 = time.perf_counter()
                points = deskew(points, tt, motion[0], motion[1]).astype(np.float32)
                deskew_ms = (time.perf_counter() - t0) * 1e3
            elif rc.polish != "none" and stamp_ns is not None:
                keep_raw = (np.asarray(points, dtype=np.float32), tt, int(stamp_ns))
    pc = polish_cloud(config, points, defer=defer, threads=threads) if rc.polish != "none" else None
    res = _sampled(pp, pc, points, lazy)
    if deskew_ms is not None:
        res.timings_ms["deskew"] = deskew_ms
        res.timings_ms["total"] += deskew_ms
    if keep_raw is not None:
        res.raw_points, res.times, res.stamp_ns = keep_raw
    res.sensor = pp.sensor
    if pc is not None:
        res.polish_cloud = pc
        res.timings_ms["polish_prepare"] = res.polish_cloud.prepare_ms
        res.timings_ms["total"] += res.polish_cloud.prepare_ms
    return res


def with_sensor(config: Config, points: np.ndarray, driver: str | None = None) -> Config:
    """``config`` with ``preprocess.sensor`` settled (``"auto"``: from ``driver`` or the shape of ``points`` (N, 3))
    and that sensor's defaults applied (:func:`core.sensors.resolve`); ``config`` itself when nothing changes."""
    pp = config.preprocess
    name = guess_sensor(points, driver) if pp.sensor == "auto" else pp.sensor
    resolved = resolve(pp, name)
    return config if resolved is pp else dataclasses.replace(config, preprocess=resolved)


def _sampled(pp: Any, pc: PolishCloud | None, points: np.ndarray, lazy: bool,
             ordered: bool = False) -> PreprocessResult:
    """The network's points of a scan (N, 3) whose precision-stage cloud is ``pc`` (or None); ``ordered``: the
    cloud's centroids come in an order of their own (not small_gicp's voxel grid's)."""
    # the shared grid, unless a raw scan's is too sparse for min_candidates (about half a grid is ground): then the
    # scan's own grid, which shrinks its voxel for a sparse cloud (a view's points are a grid already: never)
    enough = pc is not None and pc.n_points >= (pp.num_points if ordered else max(pp.num_points, 2 * pp.min_candidates))
    if pc is not None and pp.share_grid and enough:
        # one voxel grid per scan: the precision stage's, whose centroids the network's points are sampled from
        if lazy:  # sampled on first read, from the precision-stage cloud's grid: the same numbers
            res = PreprocessResult(None, None, len(points), pc.n_cropped, 0, timings_ms={"total": 0.0},
                                   pending_sample=(preprocess, pp, pp.seed))
        else:
            grid = pc.points() if ordered else canonical_order(pc.points())
            res = preprocess(grid.astype(np.float32), pp, gridded=True)
        res.n_input, res.n_valid = len(points), pc.n_cropped
        return res
    if lazy and pc is not None and not ordered and pc.n_points >= MIN_POLISH_POINTS:
        # a sparse raw scan's own grid: sampled on first read from the scan (one with nearly nothing in the crop
        # fails here, as a scan should: at once)
        return PreprocessResult(None, None, len(points), pc.n_cropped, 0, timings_ms={"total": 0.0},
                                pending_sample=(preprocess, pp, pp.seed, np.asarray(points, np.float32)))
    return preprocess(points, pp)


def ready_to_judge(config: Config, pre: PreprocessResult) -> PreprocessResult:
    """``pre`` with what the good start's verdict reads of this scan alone built now and kept on its precision-stage
    cloud: its target tables (core/target_surface.py: its voxels, direction cells, own roughness, at
    ``registration.verdict_dist``) and the spread subset of its voxels it judges (``registration.good_start_points``).
    In a stream each scan is the source of one pair and the target of the next: a caller with time between the pairs
    (the node's registration process, once the pair the scan was the source of is answered) takes them off the next
    answer's path; the numbers are those the verdict would compute. Nothing when the cloud waits for its k-d tree (or
    has none)."""
    from deepbbs_ros.core import target_surface

    pc, rc = pre.polish_cloud, config.registration
    if pc is not None and pc.pending is None and pc.tree is not None:
        target_surface._target(pc, rc.verdict_dist)
        target_surface.spread_points(pc, rc.good_start_points, rc.polish_voxel or 0.5)
    return pre


def prepare_view(config: Config, view: PolishView) -> PreprocessResult:
    """A part of a prepared map cloud (:class:`PolishView`: a map crop, frame A) -> its :class:`PreprocessResult`:
    the network's points sampled from the view's centroids (in the order given: the map's), ``polish_cloud`` the
    view (nothing more to prepare)."""
    t0 = time.perf_counter()
    res = _sampled(config.preprocess, view, view.local.astype(np.float32), lazy=False, ordered=True)
    res.polish_cloud = view
    res.timings_ms["polish_prepare"] = 0.0
    res.timings_ms["view"] = (time.perf_counter() - t0) * 1e3
    return res


def polish_cloud(config: Config, points: np.ndarray, *, defer: bool = False, threads: int = 1) -> PolishCloud:
    """Raw scan (N, 3) -> its precision-stage cloud (``registration.polish_*``, the preprocess crop)."""
    pp, rc = config.preprocess, config.registration
    points = as_xyz(points, "polish_cloud", dtype=None)
    if pp.self_filter_box:  # the robot's own body is no part of the scene
        points = np.compress(crop_mask(points, pp), points, axis=0)
    return prepare_polish_cloud(
        points, rc.polish_voxel, rc.polish_neighbors,
        registration_type=SMALL_GICP_TYPE[rc.polish],
        min_range=pp.min_range, max_range=pp.max_range, threads=threads, defer=defer,
        max_voxels=rc.polish_max_voxels, voxel_angle=rc.polish_voxel_angle)


def deskew_prepared(config: Config, pre: PreprocessResult, motion: tuple[np.ndarray, float], *,
                    threads: int = 1) -> PreprocessResult:
    """A copy of ``pre`` (kept raw points and times: ``prepare_scan(points, times, stamp_ns)``) with
    ``deskewed_cloud``, its precision-stage cloud deskewed to the stamp with ``motion`` = (``T_a_b`` (4, 4),
    seconds from a to b), the scan's own velocity. The sampled points stay as measured (the network is trained
    on raw and compensated sweeps alike)."""
    if pre.raw_points is None or pre.times is None or pre.polish_cloud is None:
        return pre
    if pre.sensor != "auto":  # the defaults of the sensor the scan was prepared with
        config = dataclasses.replace(config, preprocess=resolve(config.preprocess, pre.sensor))
    t0 = time.perf_counter()
    cloud = _deskewed_cloud(config, pre, motion[0], motion[1], threads)
    ms = (time.perf_counter() - t0) * 1e3
    timings = {**pre.timings_ms, "deskew": ms, "total": pre.timings_ms.get("total", 0.0) + ms}
    out = copy.copy(pre)  # not dataclasses.replace: that would read (and so run) a waiting sampling
    out.deskewed_cloud, out.velocity, out.deskew, out.timings_ms = cloud, motion, "deskewed", timings
    return out


def _deskewed_cloud(config: Config, pre: PreprocessResult, T: np.ndarray, dt: float, threads: int) -> PolishCloud:
    """The precision-stage cloud of ``pre`` deskewed with the twist ``log(T) / dt``: its voxel centroids moved
    with the times their azimuths were measured at (:class:`SweepTimes`, fitted to the raw scan; covariances and
    k-d tree rebuilt, about half the cost of a full preparation), or, when the times do not follow the azimuth,
    the raw scan deskewed point by point and prepared again."""
    rc = config.registration
    sweep = SweepTimes.fit(pre.raw_points, pre.times)
    if sweep is None:
        return polish_cloud(config, deskew(pre.raw_points, pre.times, T, dt).astype(np.float32), threads=threads)
    c = pre.polish_cloud.points()
    return prepared_cloud(deskew(c, sweep(c), T, dt), rc.polish_neighbors, SMALL_GICP_TYPE[rc.polish], threads)
