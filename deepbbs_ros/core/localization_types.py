"""The data of global localization (no ROS): what a localization answers, a prepared scan, a candidate place's
crop and a registration's answer on it, and the small pose and input helpers they share.

:class:`LocalizationResult` is what :class:`~deepbbs_ros.core.localization.MapLocalizer` and
:class:`~deepbbs_ros.core.tracking.MapTracker` return; :class:`PreparedScan` what ``MapLocalizer.prepare`` makes
of a raw scan; ``_Crop`` / ``_Answer`` the global search's own. Frames as in core/localization.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from deepbbs_ros.errors import DeepBBSError, LocalizationError
from deepbbs_ros.reprs import short_repr

MIN_SCAN_POINTS = 50  # a scan with fewer finite points is refused


@dataclass
class LocalizationResult:
    """One scan's pose in the map, or why there is none.

    Attributes:
        T_map_scan: (4, 4) float64, p_map = R p_scan + t; the best estimate even when not valid (then not to be
            used; identity when there is none).
        valid: the verdict accepted it and nothing else looked alike (publish only when True).
        score: the verdict's score of the chosen pose (nan when none).
        mode: "global" (searched the map), "tracking" (from a guess / prediction) or "hint" (near a pose hint).
        reason: "" when valid; else one line why no pose.
        event: set by :class:`MapTracker`: "found", "tracking", "lost", "relocalized", "searching".
        candidates: candidate places registered (global), 1 when tracking from the guess alone.
        path: which registration path answered: "gicp" (tracking, good start), "deepbbs", "search" (a local search
            after the guess was rejected).
        timings_ms: "preprocess", "describe", "rank", "crop", "register", "gicp", "probe", "refine", "covariance",
            "total" (those that ran).
        crop: (M, 3) float32 the map points used (the chosen crop's GICP cloud), map frame; None when none.
        place: index into :attr:`MapLocalizer.places` of the crop that answered (-1: a crop at the guess / none).
        alternatives: [(x, y, score)] of the other valid answers of a global search (map frame, m).
        probability: the map verdict's probability that ``T_map_scan`` is right (core/map_verdict.py; nan when not
            judged).
        covariance: (6, 6) float64 covariance of ``T_map_scan`` for every valid pose (ROS order x, y, z, rot x, rot y,
            rot z; position error in the map frame, rotation error a left perturbation: core/covariance.py), from the
            GICP of the scan on the crop at the pose; None when not valid or none could be computed.
    """

    __repr__ = short_repr

    T_map_scan: np.ndarray
    valid: bool
    score: float
    mode: str
    reason: str
    event: str = ""
    candidates: int = 0
    path: str = ""
    timings_ms: dict[str, float] = field(default_factory=dict)
    crop: np.ndarray | None = None
    place: int = -1
    alternatives: list[tuple[float, float, float]] = field(default_factory=list)
    covariance: np.ndarray | None = None
    probability: float = float("nan")


@dataclass
class PreparedScan:
    """A scan made ready for :meth:`MapLocalizer.localize` by :meth:`MapLocalizer.prepare` (e.g. on arrival)."""

    points: np.ndarray  # (N, 3) float32 the scan's finite points, sensor frame, metres
    pre: Any  # its PreprocessResult (GICP cloud with k-d tree and covariances; sampling lazy)
    preprocess_ms: float  # what preparing it took


@dataclass
class _Crop:
    T_map_place: np.ndarray  # (4, 4) the crop's frame (gravity-aligned, origin at the place's sensor position)
    pre: Any  # its PreprocessResult (GICP cloud included)
    map_cloud: np.ndarray | None = None  # (M, 3) float32 its GICP cloud in the map frame (LocalizationResult.crop)


@dataclass
class _Answer:
    score: float
    ok: bool  # accepted: the map verdict's probability reaches localization.min_probability
    T: np.ndarray  # T_map_scan
    place: int
    crop: _Crop
    probe: bool = False  # from the GICP probe around the best answer
    gicp: bool = False  # from GICP alone (the network's answer failed or scored low)
    prob: float = 0.0  # the map verdict's probability that the pose is right (core/map_verdict.py)
    refined: bool = False  # MapLocalizer._refined has seen it


def answer_rank(a: _Answer) -> tuple[bool, float]:
    """The order of answers, best first (``min``, ``sort``): accepted ones, then by the verdict's score (the fitness:
    among right poses the closer fit; a probability saturates near 1)."""
    return (not a.ok, -a.score)


def _crop_cloud(crop: _Crop) -> np.ndarray | None:
    """(M, 3) float32 the crop's GICP cloud in the map frame (kept with the crop)."""
    if crop.map_cloud is None:
        pc = getattr(crop.pre, "polish_cloud", None)
        if pc is None:
            return None
        p = np.asarray(pc.points(), dtype=np.float64)[:, :3]
        crop.map_cloud = (p @ crop.T_map_place[:3, :3].T + crop.T_map_place[:3, 3]).astype(np.float32)
    return crop.map_cloud


def _heading(T: np.ndarray) -> np.ndarray:
    """(2,) the unit horizontal heading (x axis) of a pose T (4, 4)."""
    return T[:2, 0] / max(float(np.linalg.norm(T[:2, 0])), 1e-9)


def _yaw(T: np.ndarray) -> float:
    """The yaw (rad) of a pose T (4, 4): the heading of its x axis."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def _rz(yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def _as_cloud(points: Any, name: str) -> np.ndarray:
    """(N, 3) float32 (NaN rows kept) or LocalizationError naming ``name``."""
    from deepbbs_ros.core.points import as_xyz

    try:
        return as_xyz(points, name)
    except DeepBBSError as err:
        raise LocalizationError(str(err)) from err
