"""PNG plots of a replay run (matplotlib, Agg backend: no display needed).

Modules: this one plots the pair protocol; :mod:`~deepbbs_ros.replay.plot_odometry` the odometry trajectories and
errors, :mod:`~deepbbs_ros.replay.plot_localization` maps and localization, :mod:`~deepbbs_ros.replay.plot_style` what
they share; every plot's function is imported from here too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros.replay.methods import topic_name
from deepbbs_ros.replay.plot_localization import (
    EVENT_COLORS,
    EVENT_OTHER,
    MAP_DRAW_POINTS,
    MODE_COLORS,
    draw_map,
    map_figure,
    plot_localization,
    plot_map,
)
from deepbbs_ros.replay.plot_odometry import SPREAD_FOR_LOG, errors_over_time_figure, plot_odometry, trajectory_figure
from deepbbs_ros.replay.plot_style import (
    BIG_COORD,
    MIN_XY_RATIO,
    STRETCHED_XY_RATIO,
    ZERO_FLOOR,
    cdf,
    log_or_note,
    on_log_axis,
    pyplot,
    save,
    ticks,
)
from deepbbs_ros.replay.runner import PairResults

__all__ = [
    "BIG_COORD", "EVENT_COLORS", "EVENT_OTHER", "MAP_DRAW_POINTS", "MIN_XY_RATIO", "MODE_COLORS", "SPREAD_FOR_LOG",
    "STRETCHED_XY_RATIO", "ZERO_FLOOR", "draw_map", "errors_over_time_figure", "map_figure", "plot_localization",
    "plot_map", "plot_odometry", "plot_pairs", "topic_name", "trajectory_figure",
]


def plot_pairs(run: Path, res: PairResults, rot_thresh: float, trans_thresh: float) -> list[Path]:
    """``errors_cdf.png`` (rotation / translation error CDFs per method), ``errors_hist.png`` and
    ``errors_over_pairs.png``; every figure has one legend, above its panels."""
    plt = pyplot()
    out = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
    rot_all = [r.rot_err_deg for r in res.records]
    tr_all = [r.trans_err_m for r in res.records]
    for name in res.methods:
        recs = res.of(name)
        cdf(axes[0], [r.rot_err_deg for r in recs], name)
        cdf(axes[1], [r.trans_err_m for r in recs], name)
    axes[0].axvline(rot_thresh, color="k", ls=":", lw=1, label="success threshold")
    axes[1].axvline(trans_thresh, color="k", ls=":", lw=1)
    log_or_note(axes[0], "x", rot_all)
    log_or_note(axes[1], "x", tr_all)
    axes[0].set(xlabel="rotation error [deg]", ylabel="fraction of registrations",
                title=f"Rotation error CDF (success: <= {rot_thresh:g} deg)", ylim=(0.0, 1.02))
    axes[1].set(xlabel="translation error [m]", title=f"Translation error CDF (success: <= {trans_thresh:g} m)",
                ylim=(0.0, 1.02))
    save(fig, run / "errors_cdf.png", out, grid=axes, legend=axes[:1])

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
        ax.yaxis.set_major_locator(ticks(6, integer=True))
    save(fig, run / "errors_hist.png", out, legend=axes[:1])

    fig, axes = plt.subplots(2, 1, figsize=(10, 6.4), sharex=True, layout="constrained")
    zeros = False
    for name in res.methods:
        recs = [r for r in res.of(name) if r.trial == 0]
        x = [r.pair for r in recs]
        rot, z1 = on_log_axis([r.rot_err_deg for r in recs])
        tr, z2 = on_log_axis([r.trans_err_m for r in recs])
        zeros = zeros or z1 or z2
        axes[0].plot(x, rot, ".-", label=name)
        axes[1].plot(x, tr, ".-", label=name)
    trial0 = [r for r in res.records if r.trial == 0]
    log_or_note(axes[0], "y", [r.rot_err_deg for r in trial0])
    log_or_note(axes[1], "y", [r.trans_err_m for r in trial0])
    axes[0].set(ylabel="rotation error [deg]", title="Error per pair (trial 0)"
                + (f"; an error of 0 is drawn at {ZERO_FLOOR:g}" if zeros else ""))
    axes[1].set(ylabel="translation error [m]", xlabel="pair")
    axes[1].xaxis.set_major_locator(ticks(10, integer=True))  # pairs are whole numbers
    save(fig, run / "errors_over_pairs.png", out, grid=axes, legend=axes[:1])
    return out
