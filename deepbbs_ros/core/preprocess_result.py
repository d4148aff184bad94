"""The result of preprocessing a scan, whose sampling may wait for its first use (no ROS import)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from deepbbs_ros.core.sampling import canonical_order
from deepbbs_ros.reprs import short_repr, short_value


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
    # (pipeline, cfg, seed) while the sampling waits (``prepare_scan(..., lazy=True)``: on the grid of ``polish_cloud``,
    # put in :func:`canonical_order`; (pipeline, cfg, seed, raw scan (N, 3)) for a scan too sparse for that grid: on
    # its own), ``pipeline`` being ``core.preprocess.preprocess``, given by the caller that builds the result: the first
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
            preprocess, cfg, seed, *raw = spec
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
