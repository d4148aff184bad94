"""Odometry plots of a replay run: each method's trajectory over the ground truth (top view), and the errors and
runtime over time."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.replay.plot_style import (
    cdf,
    figure_legend,
    finish,
    log_or_note,
    pyplot,
    save,
    ticks,
    xy_axes,
    xy_frame,
)
from deepbbs_ros.replay.runner import OdometryResults


def plot_odometry(run: Path, res: OdometryResults) -> list[Path]:
    """``trajectory_xy.png`` (top view against ground truth, then the ground-truth path coloured by each
    method's position error), ``errors_over_time.png`` (position error and RPE per frame), ``rpe_cdf.png``."""
    plt = pyplot()
    out = []
    n = res.frames
    if n == 0:
        return out
    gt = np.stack(res.T_world_gt[:n]) if res.has_ground_truth else None
    t = (np.asarray(res.stamps_ns[:n], dtype=np.int64) - res.stamps_ns[0]) * 1e-9

    ests = {name: np.stack(res.T_world_est[name][:n]) for name in res.methods}
    save(trajectory_figure(ests, gt), run / "trajectory_xy.png", out)
    runtime_ms = {name: res.runtime_ms[name][:n] for name in res.methods}
    save(errors_over_time_figure(t, ests, runtime_ms, gt), run / "errors_over_time.png", out)

    if gt is not None:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
        for name in res.methods:
            P = np.stack(res.T_world_est[name][:n])
            tr, rot = metrics.rpe(P, gt)
            cdf(axes[0], tr, name)
            cdf(axes[1], rot, name)
        rpes = [metrics.rpe(P, gt) for P in ests.values()]
        log_or_note(axes[0], "x", np.concatenate([t for t, _ in rpes]) if rpes else [])
        log_or_note(axes[1], "x", np.concatenate([r for _, r in rpes]) if rpes else [])
        axes[0].set(xlabel="RPE translation [m/frame]", ylabel="fraction of frames", title="RPE CDF")
        axes[1].set(xlabel="RPE rotation [deg/frame]")
        save(fig, run / "rpe_cdf.png", out, grid=axes, legend=axes[:1])
    return out


def trajectory_figure(ests: dict[str, np.ndarray], gt: np.ndarray | None):
    """The top-view figure of ``trajectory_xy.png``: (N, 4, 4) poses per method and the ground truth (or None).

    Left: every trajectory over the ground truth; then, with ground truth, one panel per method with the
    ground-truth path coloured by that method's position error (its own colour scale, below the panel:
    one diverged method does not flatten the others). One legend, above the panels, outside the data."""
    plt = pyplot()
    panels = 1 + (len(ests) if gt is not None else 0)
    fig, axs = plt.subplots(1, panels, figsize=(4.6 * panels + 0.6, 5.6), squeeze=False, layout="constrained")
    axs = axs[0]
    paths = ([gt[:, :2, 3]] if gt is not None else []) + [P[:, :2, 3] for P in ests.values()]
    origin, xlim, ylim, to_scale = xy_frame(paths)
    ax = axs[0]
    if gt is not None:
        ax.plot(gt[:, 0, 3] - origin[0], gt[:, 1, 3] - origin[1], "k--", lw=2, label="ground truth")
    for name, P in ests.items():
        ax.plot(P[:, 0, 3] - origin[0], P[:, 1, 3] - origin[1], lw=1.2, label=name)
    xy_axes(ax, origin, xlim, ylim, to_scale, "Trajectory (top view)")
    if gt is not None:
        for ax, (name, P) in zip(axs[1:], ests.items()):
            e = np.linalg.norm(P[:, :3, 3] - gt[:, :3, 3], axis=1)
            finite = e[np.isfinite(e)]
            vmax = max(float(finite.max()) if finite.size else 0.0, 1e-3)
            sc = ax.scatter(gt[:, 0, 3] - origin[0], gt[:, 1, 3] - origin[1], c=e, cmap="viridis", vmin=0.0,
                            vmax=vmax, s=14, zorder=3)
            worst = f"max {float(finite.max()):.3f} m" if finite.size else "no finite estimate"
            xy_axes(ax, origin, xlim, ylim, to_scale, f"{name}: position error ({worst})")
            ax.set_ylabel("")
            bar = fig.colorbar(sc, ax=ax, orientation="horizontal", location="bottom", shrink=0.9, pad=0.02)
            bar.set_label("position error [m] (unaligned)", fontsize=8)
            bar.ax.tick_params(labelsize=8)
            bar.ax.xaxis.set_major_locator(ticks(4))
    figure_legend(fig, axs[0])
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
    plt = pyplot()
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
    finish(fig, grid=axes, legend=axes[-1:])
    return fig

