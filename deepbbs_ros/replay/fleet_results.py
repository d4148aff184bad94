"""A fleet run's results: one :class:`Recording` row per recording, the :class:`FleetResult`, and the pooled figures
per method computed from the per-recording metrics (:func:`pool_metrics`; see :mod:`deepbbs_ros.replay.fleet`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any


# --------------------------------------------------------------------------------------------------
# pooled figures
# --------------------------------------------------------------------------------------------------
def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and v is not None and math.isfinite(v) else float("nan")


def _wmean(values: list[float], weights: list[float]) -> float | None:
    pairs = [(v, w) for v, w in zip(values, weights) if math.isfinite(v) and w > 0]
    total = sum(w for _, w in pairs)
    return sum(v * w for v, w in pairs) / total if total else None


def _wrms(values: list[float], weights: list[float]) -> float | None:
    m = _wmean([v * v for v in values], weights)
    return math.sqrt(m) if m is not None else None


def _max(values: list[float]) -> float | None:
    vals = [v for v in values if math.isfinite(v)]
    return max(vals) if vals else None


def get_dotted(d: dict, dotted: str) -> Any:
    for k in dotted.split("."):
        d = d.get(k) if isinstance(d, dict) else None
    return d


def pool_metrics(mode: str, per_recording: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Pooled figures per method from the per-recording ``metrics.json["methods"]`` of every recording
    that has one (a failed recording has none and adds nothing).

    Pairs mode, weights = each recording's scored registrations (registrations less failed ones): mean
    errors and runtime are weighted means, RMSE the weighted root mean square, max the max; success rate
    weighted by registrations (a failed registration is a miss, as in one recording). Odometry: KITTI drift
    weighted by segments (the mean over every segment of the fleet), ATE RMSE over every frame of the
    fleet (each recording aligned on its own), RPE and runtime weighted by registered frames (frames - 1),
    fps = 1000 / pooled mean runtime. Localization: counts summed, shares over every scan of the fleet, the mean
    time to first pose over the recordings, tracking latency weighted by scans. Percentiles need the individual
    values and are not pooled.
    """
    names: list[str] = []
    for mm in per_recording:
        names += [n for n in mm if n not in names]
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        ms = [mm[name] for mm in per_recording if name in mm]
        if mode == "pairs":
            reg = [float(m.get("registrations", 0) or 0) for m in ms]
            scored = [r - float(m.get("failed", 0) or 0) for r, m in zip(reg, ms)]

            def err(key, m_list=ms, w=scored):
                return {"mean": _wmean([_num(m[key]["mean"]) for m in m_list], w),
                        "rmse": _wrms([_num(m[key]["rmse"]) for m in m_list], w),
                        "max": _max([_num(m[key]["max"]) for m in m_list])}

            out[name] = {
                "recordings": len(ms), "pairs": sum(int(m.get("pairs", 0) or 0) for m in ms),
                "registrations": int(sum(reg)), "failed": sum(int(m.get("failed", 0) or 0) for m in ms),
                "rot_err_deg": err("rot_err_deg"), "trans_err_m": err("trans_err_m"),
                "success_rate": _wmean([_num(m.get("success_rate")) for m in ms], reg),
                "runtime_ms": {"mean": _wmean([_num(m["runtime_ms"]["mean"]) for m in ms], scored)},
            }
        elif mode == "localization":
            scans = [float(m.get("scans", 0) or 0) for m in ms]
            total = sum(scans)

            def count(key, m_list=ms):
                vals = [m.get(key) for m in m_list]
                return None if any(v is None for v in vals) else int(sum(vals))

            placed, correct = count("placed"), count("correct")
            out[name] = {
                "recordings": len(ms), "scans": int(total), "placed": placed, "correct": correct,
                "placed_share": placed / total if total and placed is not None else None,
                "correct_share": correct / total if total and correct is not None else None,
                "wrong_published": count("wrong_published"), "recoveries": count("recoveries"),
                "time_to_first_pose_ms": {"mean": _wmean([_num(m.get("time_to_first_pose_ms")) for m in ms],
                                                         [1.0] * len(ms))},
                "latency_tracking_ms": {"mean": _wmean([_num(get_dotted(m, "latency_tracking_ms.mean")) for m in ms],
                                                       scans)},
            }
        else:
            frames = [float(m.get("frames", 0) or 0) for m in ms]
            reg = [max(0.0, f - 1) for f in frames]
            segs = [float(m.get("kitti_segments", 0) or 0) for m in ms]
            rt = _wmean([_num(m["runtime_ms"]["mean"]) for m in ms], reg)
            out[name] = {
                "recordings": len(ms), "frames": int(sum(frames)), "kitti_segments": int(sum(segs)),
                "kitti_t_err_pct": _wmean([_num(m.get("kitti_t_err_pct")) for m in ms], segs),
                "kitti_r_err_deg_per_100m": _wmean([_num(m.get("kitti_r_err_deg_per_100m")) for m in ms], segs),
                "ate_rmse_m": _wrms([_num(m.get("ate_rmse_m")) for m in ms], frames),
                "rpe_trans_m": {"mean": _wmean([_num(m["rpe_trans_m"]["mean"]) for m in ms], reg)},
                "rpe_rot_deg": {"mean": _wmean([_num(m["rpe_rot_deg"]["mean"]) for m in ms], reg)},
                "runtime_ms": {"mean": rt},
                "fps": 1000.0 / rt if rt else None,
                "failed_frames": sum(int(m.get("failed_frames", 0) or 0) for m in ms),
            }
    return out


# --------------------------------------------------------------------------------------------------
# the rows
# --------------------------------------------------------------------------------------------------
@dataclass
class Recording:
    """One row of the fleet summary."""

    name: str
    source: str
    status: str = "not run"  # ok | incomplete (partial results written) | failed | not run
    error: str = ""
    seconds: float | None = None
    frames_read: int | None = None
    methods: dict[str, Any] = field(default_factory=dict)

    def row(self) -> dict[str, Any]:
        return {"name": self.name, "source": self.source, "status": self.status, "error": self.error,
                "seconds": self.seconds, "frames_read": self.frames_read,
                "metrics": f"{self.name}/metrics.json" if self.status in ("ok", "incomplete") else None,
                "methods": self.methods}


@dataclass
class FleetResult:
    mode: str
    recordings: list[Recording]
    workers: int
    address: str
    wall_s: float = 0.0
    complete: bool = True
    errors: list[str] = field(default_factory=list)

    @property
    def pooled(self) -> dict[str, dict[str, Any]]:
        return pool_metrics(self.mode, [r.methods for r in self.recordings if r.methods])

