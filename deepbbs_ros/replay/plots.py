"""PNG plots of a replay run (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.replay.methods import topic_name
from deepbbs_ros.replay.runner import LocalizationResults, OdometryResults, PairResults


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _cdf(ax, values, label):
    v = np.asarray(values, dtype=np.float64)
    v = np.sort(v[np.isfinite(v)])
    if v.size:
        ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=label)


def _finite_positive(values) -> bool:
    v = np.asarray(values, dtype=np.float64)
    return bool(np.any(np.isfinite(v) & (v > 0)))


def _log_or_note(ax, axis: str, values) -> None:
    """Log scale on ``axis`` when some value is finite and > 0, else a linear axis and a note saying
    why it is empty (every registration failed, or an exact zero error)."""
    if _finite_positive(values):
        (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    else:
        ax.text(0.5, 0.5, "no finite error > 0 to plot", transform=ax.transAxes, ha="center", va="center",
                color="0.4")


def _figure_legend(fig, ax) -> None:
    """One legend for the whole figure, above its panels (never on the data), from ``ax``'s labelled lines."""
    handles, labels = ax.get_legend_handles_labels()
    if labels:
        fig.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), 6), fontsize=9, frameon=False)


#: errors of exactly 0 (a log axis cannot show them) are drawn at this floor, deg or m
ZERO_FLOOR = 1e-4


def _on_log_axis(values) -> tuple[np.ndarray, bool]:
    """(values with exact zeros raised to :data:`ZERO_FLOOR`, whether any was)."""
    v = np.asarray(values, dtype=np.float64)
    zero = v == 0.0
    return np.where(zero, ZERO_FLOOR, v), bool(zero.any())


def plot_pairs(run: Path, res: PairResults, rot_thresh: float, trans_thresh: float) -> list[Path]:
    """``errors_cdf.png`` (rotation / translation error CDFs per method), ``errors_hist.png`` and
    ``errors_over_pairs.png``; every figure has one legend, above its panels."""
    plt = _plt()
    out = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    rot_all = [r.rot_err_deg for r in res.records]
    tr_all = [r.trans_err_m for r in res.records]
    for name in res.methods:
        recs = res.of(name)
        _cdf(axes[0], [r.rot_err_deg for r in recs], name)
        _cdf(axes[1], [r.trans_err_m for r in recs], name)
    axes[0].axvline(rot_thresh, color="k", ls=":", lw=1, label="success threshold")
    axes[1].axvline(trans_thresh, color="k", ls=":", lw=1)
    _log_or_note(axes[0], "x", rot_all)
    _log_or_note(axes[1], "x", tr_all)
    axes[0].set(xlabel="rotation error [deg]", ylabel="fraction of registrations",
                title=f"Rotation error CDF (success: <= {rot_thresh:g} deg)", ylim=(0.0, 1.02))
    axes[1].set(xlabel="translation error [m]", title=f"Translation error CDF (success: <= {trans_thresh:g} m)",
                ylim=(0.0, 1.02))
    for ax in axes:
        ax.grid(alpha=0.3)
    _figure_legend(fig, axes[0])
    out.append(run / "errors_cdf.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    for name in res.methods:
        recs = res.of(name)
        for ax, vals in ((axes[0], [r.rot_err_deg for r in recs]), (axes[1], [r.trans_err_m for r in recs])):
            v = np.asarray(vals, dtype=np.float64)
            v = v[np.isfinite(v)]
            if v.size:
                ax.hist(np.log10(np.maximum(v, ZERO_FLOOR)), bins=30, alpha=0.5, label=name)
    axes[0].set(xlabel="log10 rotation error [deg]", ylabel="registrations", title="Rotation error histogram")
    axes[1].set(xlabel="log10 translation error [m]", title="Translation error histogram")
    for ax in axes:
        ax.yaxis.set_major_locator(_ticks(6, integer=True))
    _figure_legend(fig, axes[0])
    out.append(run / "errors_hist.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(2, 1, figsize=(10, 6.4), sharex=True, layout="constrained")
    zeros = False
    for name in res.methods:
        recs = [r for r in res.of(name) if r.trial == 0]
        x = [r.pair for r in recs]
        rot, z1 = _on_log_axis([r.rot_err_deg for r in recs])
        tr, z2 = _on_log_axis([r.trans_err_m for r in recs])
        zeros = zeros or z1 or z2
        axes[0].plot(x, rot, ".-", label=name)
        axes[1].plot(x, tr, ".-", label=name)
    trial0 = [r for r in res.records if r.trial == 0]
    _log_or_note(axes[0], "y", [r.rot_err_deg for r in trial0])
    _log_or_note(axes[1], "y", [r.trans_err_m for r in trial0])
    axes[0].set(ylabel="rotation error [deg]", title="Error per pair (trial 0)"
                + (f"; an error of 0 is drawn at {ZERO_FLOOR:g}" if zeros else ""))
    axes[1].set(ylabel="translation error [m]", xlabel="pair")
    axes[1].xaxis.set_major_locator(_ticks(10, integer=True))  # pairs are whole numbers
    for ax in axes:
        ax.grid(alpha=0.3)
    _figure_legend(fig, axes[0])
    out.append(run / "errors_over_pairs.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)
    return out


#: a top view is drawn to scale (a square panel, the short axis padded) while the path's short extent is at least
#: this share of its long one; a flatter path (a straight drive) is drawn not to scale, its short axis padded to
#: STRETCHED_XY_RATIO of the long one, so that its lateral errors stay visible
MIN_XY_RATIO = 0.1
STRETCHED_XY_RATIO = 0.25
#: coordinates this large (UTM, map frames) are plotted relative to the first ground-truth position
BIG_COORD = 1e4


def _xy_frame(paths: list[np.ndarray]) -> tuple[np.ndarray, tuple, tuple, bool]:
    """The top view of (N, 2) paths: (origin subtracted from every path, x limits, y limits, to scale).

    Equal scales on both axes (square limits) while the paths' extent is not flatter than
    :data:`MIN_XY_RATIO`; a flatter one (a straight drive) has its short axis padded to
    :data:`STRETCHED_XY_RATIO` of the long one and is drawn not to scale. Either way no axis is a strip
    whose tick labels run into each other."""
    pts = np.concatenate([p[np.isfinite(p).all(axis=1)] for p in paths] + [np.zeros((0, 2))])
    if not len(pts):
        return np.zeros(2), (-1.0, 1.0), (-1.0, 1.0), True
    origin = np.floor(pts[0]) if np.abs(pts).max() > BIG_COORD else np.zeros(2)  # whole metres: exact labels
    lo, hi = pts.min(axis=0) - origin, pts.max(axis=0) - origin
    span = np.maximum(hi - lo, 1e-9)
    longest = max(float(span.max()), 1.0)  # at least 1 m across: a car standing still
    to_scale = float(span.min()) >= MIN_XY_RATIO * longest
    half = np.maximum(span, longest if to_scale else STRETCHED_XY_RATIO * longest) / 2 * 1.08  # 8 % margin
    if to_scale:
        half[:] = half.max()
    mid = (lo + hi) / 2
    return origin, (mid[0] - half[0], mid[0] + half[0]), (mid[1] - half[1], mid[1] + half[1]), to_scale


def _xy_axes(ax, origin: np.ndarray, xlim: tuple, ylim: tuple, to_scale: bool, title: str) -> None:
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal" if to_scale else "auto", adjustable="box")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
        fmt = ScalarFormatter(useOffset=False)
        fmt.set_scientific(False)
        axis.set_major_formatter(fmt)
    shifted = bool(origin.any())
    ax.set_xlabel(f"x - {origin[0]:.0f} [m]" if shifted else "x [m]")
    ax.set_ylabel(f"y - {origin[1]:.0f} [m]" if shifted else "y [m]")
    short = "y" if np.diff(ylim)[0] < np.diff(xlim)[0] else "x"
    ax.set_title(title + ("" if to_scale else f"\n(not to scale: {short} stretched)"), fontsize=10)
    ax.grid(alpha=0.3)


def plot_odometry(run: Path, res: OdometryResults) -> list[Path]:
    """``trajectory_xy.png`` (top view against ground truth, then the ground-truth path coloured by each
    method's position error), ``errors_over_time.png`` (position error and RPE per frame), ``rpe_cdf.png``."""
    plt = _plt()
    out = []
    n = res.frames
    if n == 0:
        return out
    gt = np.stack(res.T_world_gt[:n]) if res.has_ground_truth else None
    t = (np.asarray(res.stamps_ns[:n], dtype=np.int64) - res.stamps_ns[0]) * 1e-9

    ests = {name: np.stack(res.T_world_est[name][:n]) for name in res.methods}
    fig = trajectory_figure(ests, gt)
    out.append(run / "trajectory_xy.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig = errors_over_time_figure(t, ests, {name: res.runtime_ms[name][:n] for name in res.methods}, gt)
    out.append(run / "errors_over_time.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    if gt is not None:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
        for name in res.methods:
            P = np.stack(res.T_world_est[name][:n])
            tr, rot = metrics.rpe(P, gt)
            _cdf(axes[0], tr, name)
            _cdf(axes[1], rot, name)
        rpes = [metrics.rpe(P, gt) for P in ests.values()]
        _log_or_note(axes[0], "x", np.concatenate([t for t, _ in rpes]) if rpes else [])
        _log_or_note(axes[1], "x", np.concatenate([r for _, r in rpes]) if rpes else [])
        axes[0].set(xlabel="RPE translation [m/frame]", ylabel="fraction of frames", title="RPE CDF")
        axes[1].set(xlabel="RPE rotation [deg/frame]")
        for ax in axes:
            ax.grid(alpha=0.3)
        _figure_legend(fig, axes[0])
        out.append(run / "rpe_cdf.png")
        fig.savefig(out[-1], dpi=110)
        plt.close(fig)
    return out


def trajectory_figure(ests: dict[str, np.ndarray], gt: np.ndarray | None):
    """The top-view figure of ``trajectory_xy.png``: (N, 4, 4) poses per method and the ground truth (or None).

    Left: every trajectory over the ground truth; then, with ground truth, one panel per method with the
    ground-truth path coloured by that method's position error (its own colour scale, below the panel:
    one diverged method does not flatten the others). One legend, above the panels, outside the data."""
    plt = _plt()
    panels = 1 + (len(ests) if gt is not None else 0)
    fig, axs = plt.subplots(1, panels, figsize=(4.6 * panels + 0.6, 5.6), squeeze=False, layout="constrained")
    axs = axs[0]
    paths = ([gt[:, :2, 3]] if gt is not None else []) + [P[:, :2, 3] for P in ests.values()]
    origin, xlim, ylim, to_scale = _xy_frame(paths)
    ax = axs[0]
    if gt is not None:
        ax.plot(gt[:, 0, 3] - origin[0], gt[:, 1, 3] - origin[1], "k--", lw=2, label="ground truth")
    for name, P in ests.items():
        ax.plot(P[:, 0, 3] - origin[0], P[:, 1, 3] - origin[1], lw=1.2, label=name)
    _xy_axes(ax, origin, xlim, ylim, to_scale, "Trajectory (top view)")
    if gt is not None:
        for ax, (name, P) in zip(axs[1:], ests.items()):
            e = np.linalg.norm(P[:, :3, 3] - gt[:, :3, 3], axis=1)
            finite = e[np.isfinite(e)]
            vmax = max(float(finite.max()) if finite.size else 0.0, 1e-3)
            sc = ax.scatter(gt[:, 0, 3] - origin[0], gt[:, 1, 3] - origin[1], c=e, cmap="viridis", vmin=0.0,
                            vmax=vmax, s=14, zorder=3)
            worst = f"max {float(finite.max()):.3f} m" if finite.size else "no finite estimate"
            _xy_axes(ax, origin, xlim, ylim, to_scale, f"{name}: position error ({worst})")
            ax.set_ylabel("")
            bar = fig.colorbar(sc, ax=ax, orientation="horizontal", location="bottom", shrink=0.9, pad=0.02)
            bar.set_label("position error [m] (unaligned)", fontsize=8)
            bar.ax.tick_params(labelsize=8)
            bar.ax.xaxis.set_major_locator(_ticks(4))
    _figure_legend(fig, axs[0])
    return fig


#: an error panel whose curves' maxima differ more than this (one diverged method) gets a log scale
SPREAD_FOR_LOG = 20.0


def _error_scale(ax, curves: list[np.ndarray]) -> None:
    """Log y when one curve's maximum dwarfs another's (the small ones stay readable), else linear from 0."""
    tops = [float(np.nanmax(c[np.isfinite(c)])) for c in curves if np.isfinite(c).any()]
    positive = [v for v in tops if v > 0]
    if len(positive) >= 2 and max(positive) > SPREAD_FOR_LOG * min(positive):
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0.0)


def errors_over_time_figure(t: np.ndarray, ests: dict[str, np.ndarray], runtime_ms: dict[str, Any],
                            gt: np.ndarray | None):
    """The figure of ``errors_over_time.png``: position error (unaligned) and RPE per frame with ground truth,
    and runtime per frame; ``t`` (N,) s, (N, 4, 4) poses. One legend above the panels, outside the data."""
    plt = _plt()
    rows = 3 if gt is not None else 1
    fig, axes = plt.subplots(rows, 1, figsize=(10, 8.4 if gt is not None else 3.4), sharex=True, squeeze=False,
                             layout="constrained")
    axes = axes[:, 0]
    pos, rpe = [], []
    for name, P in ests.items():
        axes[-1].plot(t, runtime_ms[name], lw=0.8, label=name)
        if gt is not None:
            pos.append(np.linalg.norm(P[:, :3, 3] - gt[:, :3, 3], axis=1))
            rpe.append(metrics.rpe(P, gt)[0])
            axes[0].plot(t, pos[-1], lw=1)
            axes[1].plot(t[1:], rpe[-1], lw=0.8)
    if gt is not None:
        axes[0].set(ylabel="position error [m]",
                    title="Error over time (unaligned: every trajectory starts at the first ground-truth pose)")
        axes[1].set(ylabel="RPE translation [m/frame]")
        _error_scale(axes[0], pos)
        _error_scale(axes[1], rpe)
    axes[-1].set(ylabel="runtime [ms/frame]", xlabel="time [s]")
    axes[-1].set_ylim(bottom=0.0)
    for ax in axes:
        ax.grid(alpha=0.3)
    _figure_legend(fig, axes[-1])
    return fig


def _ticks(n: int, integer: bool = False):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(nbins=n, integer=integer)


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
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.6, 7.0), layout="constrained")
    P = np.asarray(T_map_sensor, dtype=np.float64).reshape(-1, 4, 4)
    sub = np.asarray(points)[:: max(1, len(points) // 20000), :2]
    origin, xlim, ylim, to_scale = _xy_frame([P[:, :2, 3], sub])
    draw_map(ax, points, origin)
    ax.plot(P[:, 0, 3] - origin[0], P[:, 1, 3] - origin[1], "-", color="tab:blue", lw=1.5, label="trajectory",
            zorder=3)
    if len(P):
        ax.plot(P[0, 0, 3] - origin[0], P[0, 1, 3] - origin[1], "o", color="tab:green", ms=6, label="start", zorder=4)
    _xy_axes(ax, origin, xlim, ylim, to_scale, f"{title}: {len(points)} points, {len(P)} scans")
    _figure_legend(fig, ax)
    return fig


def plot_map(path: Path, points: np.ndarray, T_map_sensor: np.ndarray) -> Path:
    """Write :func:`map_figure` to ``path`` (PNG)."""
    plt = _plt()
    fig = map_figure(points, T_map_sensor)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


#: the colour of each MapTracker event in the localization plots (others: EVENT_OTHER)
EVENT_COLORS = {"found": "tab:green", "tracking": "tab:blue", "relocalized": "tab:orange"}
EVENT_OTHER = "tab:purple"
MODE_COLORS = {"global": "tab:orange", "tracking": "tab:gray", "error": "tab:red"}


def plot_localization(run: Path, res: LocalizationResults, rot_thresh: float, trans_thresh: float) -> list[Path]:
    """``localization_xy.png`` (top view: the map, the ground truth, the published poses coloured by event, those
    outside the tolerance ringed, the scans without a pose at their ground truth) and ``errors_over_time.png``
    (translation and rotation error of the published poses, the tracker's time per scan by mode)."""
    plt = _plt()
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
    origin, xlim, ylim, to_scale = _xy_frame(paths)
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
    _xy_axes(ax, origin, xlim, ylim, to_scale, f"Localization in the map (top view): {share}")
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), 4), fontsize=9, frameon=False)
    out.append(run / "localization_xy.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

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
            shown, zeros = _on_log_axis(e[valid])
            ax.plot(t[valid], shown, ".-", lw=0.8, ms=4, color="tab:blue", label="published pose")
            ax.axhline(thresh, color="k", ls=":", lw=1, label="tolerance")
            _log_or_note(ax, "y", shown)
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
    for ax in axes:
        ax.grid(alpha=0.3)
    handles, labels = [], []
    for ax in axes:
        h, lab = ax.get_legend_handles_labels()
        for hh, ll in zip(h, lab):
            if ll not in labels:
                handles.append(hh)
                labels.append(ll)
    if labels:
        fig.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), 6), fontsize=9, frameon=False)
    out.append(run / "errors_over_time.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)
    return out


__all__ = ["draw_map", "map_figure", "plot_localization", "plot_map", "plot_odometry", "plot_pairs", "topic_name"]
