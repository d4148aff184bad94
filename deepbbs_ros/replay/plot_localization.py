"""Map and localization plots of a replay run: a map's top view with the sensor's pose, and every scan placed in the
prior map (events, modes, errors)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros.replay.plot_style import (
    ZERO_FLOOR,
    figure_legend,
    log_or_note,
    on_log_axis,
    pyplot,
    save,
    xy_axes,
    xy_frame,
)
from deepbbs_ros.replay.runner import LocalizationResults

#: at most this many map points are drawn in a top view (a regular subsample of the map)
MAP_DRAW_POINTS = 300_000


def draw_map(ax, points: np.ndarray, origin: np.ndarray) -> None:
    """The map's points (N, 3) in a top view, grey, shaded by height (lighter = lower), behind everything else."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) > MAP_DRAW_POINTS:
        pts = pts[:: int(np.ceil(len(pts) / MAP_DRAW_POINTS))]
    if not len(pts):
        return
    lo, hi = np.percentile(pts[:, 2], [2, 98]) if len(pts) > 1 else (0.0, 1.0)
    shade = np.clip((pts[:, 2] - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    ax.scatter(pts[:, 0] - origin[0], pts[:, 1] - origin[1], c=shade, cmap="Greys", vmin=-0.3, vmax=1.3, s=0.2,
               lw=0, rasterized=True, zorder=1)


def map_figure(points: np.ndarray, T_map_sensor: np.ndarray, title: str = "Map (top view)"):
    """Top view of a map: its points (N, 3) and the trajectory (K, 4, 4) it was built from (start marked)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.6, 7.0), layout="constrained")
    P = np.asarray(T_map_sensor, dtype=np.float64).reshape(-1, 4, 4)
    sub = np.asarray(points)[:: max(1, len(points) // 20000), :2]
    origin, xlim, ylim, to_scale = xy_frame([P[:, :2, 3], sub])
    draw_map(ax, points, origin)
    ax.plot(P[:, 0, 3] - origin[0], P[:, 1, 3] - origin[1], "-", color="tab:blue", lw=1.5, label="trajectory",
            zorder=3)
    if len(P):
        ax.plot(P[0, 0, 3] - origin[0], P[0, 1, 3] - origin[1], "o", color="tab:green", ms=6, label="start", zorder=4)
    xy_axes(ax, origin, xlim, ylim, to_scale, f"{title}: {len(points)} points, {len(P)} scans")
    figure_legend(fig, ax)
    return fig


def plot_map(path: Path, points: np.ndarray, T_map_sensor: np.ndarray) -> Path:
    """Write :func:`map_figure` to ``path`` (PNG)."""
    return save(map_figure(points, T_map_sensor), path)


#: the colour of each MapTracker event in the localization plots (others: EVENT_OTHER)
EVENT_COLORS = {"found": "tab:green", "tracking": "tab:blue", "relocalized": "tab:orange"}
EVENT_OTHER = "tab:purple"
MODE_COLORS = {"global": "tab:orange", "tracking": "tab:gray", "error": "tab:red"}


def plot_localization(run: Path, res: LocalizationResults, rot_thresh: float, trans_thresh: float) -> list[Path]:
    """``localization_xy.png`` (top view: the map, the ground truth, the published poses coloured by event, those
    outside the tolerance ringed, the scans without a pose at their ground truth) and ``errors_over_time.png``
    (translation and rotation error of the published poses, the tracker's time per scan by mode)."""
    plt = pyplot()
    out: list[Path] = []
    recs = res.records
    if not recs:
        return out
    gt = np.stack([r.T_map_gt for r in recs]) if res.has_ground_truth else None
    placed = [r for r in recs if r.valid]
    est = np.stack([r.T_map_est for r in placed]) if placed else np.zeros((0, 4, 4))

    fig, ax = plt.subplots(figsize=(8.4, 7.4), layout="constrained")
    paths = ([gt[:, :2, 3]] if gt is not None else []) + [est[:, :2, 3]]
    if res.map_xyz is not None:  # the whole map in view: where the scans were placed in it
        paths.append(np.asarray(res.map_xyz)[:: max(1, len(res.map_xyz) // 20000), :2])
    origin, xlim, ylim, to_scale = xy_frame(paths)
    if res.map_xyz is not None:
        draw_map(ax, res.map_xyz, origin)
    if res.places is not None and len(res.places):
        ax.plot(res.places[:, 0, 3] - origin[0], res.places[:, 1, 3] - origin[1], "+", color="0.55", ms=4,
                label="candidate places", zorder=2)
    if gt is not None:
        ax.plot(gt[:, 0, 3] - origin[0], gt[:, 1, 3] - origin[1], "k--", lw=1.5, label="ground truth", zorder=3)
        missed = np.array([not r.valid for r in recs])
        if missed.any():
            ax.plot(gt[missed, 0, 3] - origin[0], gt[missed, 1, 3] - origin[1], "x", color="tab:red", ms=6,
                    label="no pose (at the ground truth)", zorder=5)
    events = [r.event for r in placed]
    for event in dict.fromkeys(events):
        sel = np.array([e == event for e in events])
        ax.plot(est[sel, 0, 3] - origin[0], est[sel, 1, 3] - origin[1], "o", ms=3.5, label=event,
                color=EVENT_COLORS.get(event, EVENT_OTHER), zorder=4)
    share = f"{len(placed)} of {len(recs)} scans placed"
    if gt is not None and placed:
        wrong = np.array([not (r.rot_err_deg <= rot_thresh and r.trans_err_m <= trans_thresh) for r in placed])
        if wrong.any():
            ax.plot(est[wrong, 0, 3] - origin[0], est[wrong, 1, 3] - origin[1], "o", mfc="none", mec="tab:red",
                    mew=1.5, ms=9, label="wrong (outside tolerance)", zorder=6)
            share += f", {int(wrong.sum())} wrong"
    xy_axes(ax, origin, xlim, ylim, to_scale, f"Localization in the map (top view): {share}")
    save(fig, run / "localization_xy.png", out, legend=[ax], ncol=4)

    t = (np.asarray([r.stamp_ns for r in recs], dtype=np.int64) - recs[0].stamp_ns) * 1e-9
    rows = 3 if gt is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(10, 8.4 if gt is not None else 3.4), sharex=True, squeeze=False,
                             layout="constrained")
    axes = axes[:, 0]
    valid = np.array([r.valid for r in recs])
    if gt is not None:
        tr = np.array([r.trans_err_m for r in recs])
        rot = np.array([r.rot_err_deg for r in recs])
        any_zero = False
        for ax, e, thresh, label in ((axes[0], tr, trans_thresh, "translation error [m]"),
                                     (axes[1], rot, rot_thresh, "rotation error [deg]")):
            shown, zeros = on_log_axis(e[valid])
            ax.plot(t[valid], shown, ".-", lw=0.8, ms=4, color="tab:blue", label="published pose")
            ax.axhline(thresh, color="k", ls=":", lw=1, label="tolerance")
            log_or_note(ax, "y", shown)
            if (~valid).any():  # at the bottom of the panel
                ax.plot(t[~valid], np.full(int((~valid).sum()), 0.0), "x", color="tab:red", ms=6, label="no pose",
                        transform=ax.get_xaxis_transform(), clip_on=False)
            ax.set_ylabel(label)
            any_zero = any_zero or zeros
        axes[0].set_title("Error of the published poses against the ground truth (map frame)"
                          + (f"; an error of 0 is drawn at {ZERO_FLOOR:g}" if any_zero else ""))
    ms = np.array([r.time_ms for r in recs])
    modes = [r.mode or "error" for r in recs]
    for mode in dict.fromkeys(modes):
        sel = np.array([m == mode for m in modes])
        axes[-1].plot(t[sel], ms[sel], "o", ms=3.5, label=f"time: {mode}", color=MODE_COLORS.get(mode, EVENT_OTHER))
    axes[-1].set(ylabel="time [ms/scan]", xlabel="time [s]")
    axes[-1].set_ylim(bottom=0.0)
    save(fig, run / "errors_over_time.png", out, grid=axes, legend=axes)
    return out

