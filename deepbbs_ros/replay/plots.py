"""PNG plots of a replay run (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from deepbbs_ros import metrics
from deepbbs_ros.replay.methods import topic_name
from deepbbs_ros.replay.runner import OdometryResults, PairResults


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


def _legend(ax, **kw) -> None:
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kw)


def plot_pairs(run: Path, res: PairResults, rot_thresh: float, trans_thresh: float) -> list[Path]:
    """``errors_cdf.png`` (rotation / translation error CDFs per method), ``errors_hist.png`` and
    ``errors_over_pairs.png``."""
    plt = _plt()
    out = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    rot_all = [r.rot_err_deg for r in res.records]
    tr_all = [r.trans_err_m for r in res.records]
    for name in res.methods:
        recs = res.of(name)
        _cdf(axes[0], [r.rot_err_deg for r in recs], name)
        _cdf(axes[1], [r.trans_err_m for r in recs], name)
    axes[0].axvline(rot_thresh, color="k", ls=":", lw=1, label=f"success threshold ({rot_thresh:g} deg)")
    axes[1].axvline(trans_thresh, color="k", ls=":", lw=1, label=f"success threshold ({trans_thresh:g} m)")
    _log_or_note(axes[0], "x", rot_all)
    _log_or_note(axes[1], "x", tr_all)
    axes[0].set(xlabel="rotation error [deg]", ylabel="fraction of registrations", title="Rotation error CDF",
                ylim=(0.0, 1.02))
    axes[1].set(xlabel="translation error [m]", title="Translation error CDF", ylim=(0.0, 1.02))
    for ax in axes:
        ax.grid(alpha=0.3)
        _legend(ax, fontsize=8)
    fig.tight_layout()
    out.append(run / "errors_cdf.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name in res.methods:
        recs = res.of(name)
        for ax, vals in ((axes[0], [r.rot_err_deg for r in recs]), (axes[1], [r.trans_err_m for r in recs])):
            v = np.asarray(vals, dtype=np.float64)
            v = v[np.isfinite(v)]
            if v.size:
                ax.hist(np.log10(np.maximum(v, 1e-4)), bins=30, alpha=0.5, label=name)
    axes[0].set(xlabel="log10 rotation error [deg]", ylabel="registrations", title="Rotation error histogram")
    axes[1].set(xlabel="log10 translation error [m]", title="Translation error histogram")
    for ax in axes:
        _legend(ax)
    fig.tight_layout()
    out.append(run / "errors_hist.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for name in res.methods:
        recs = [r for r in res.of(name) if r.trial == 0]
        x = [r.pair for r in recs]
        axes[0].plot(x, [r.rot_err_deg for r in recs], ".-", label=name)
        axes[1].plot(x, [r.trans_err_m for r in recs], ".-", label=name)
    from matplotlib.ticker import MaxNLocator

    trial0 = [r for r in res.records if r.trial == 0]
    _log_or_note(axes[0], "y", [r.rot_err_deg for r in trial0])
    _log_or_note(axes[1], "y", [r.trans_err_m for r in trial0])
    axes[0].set(ylabel="rotation error [deg]", title="Error per pair (trial 0)")
    axes[1].set(ylabel="translation error [m]", xlabel="pair")
    axes[1].xaxis.set_major_locator(MaxNLocator(integer=True))  # pairs are whole numbers
    for ax in axes:
        ax.grid(alpha=0.3)
    _legend(axes[0])
    fig.tight_layout()
    out.append(run / "errors_over_pairs.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)
    return out


def plot_odometry(run: Path, res: OdometryResults) -> list[Path]:
    """``trajectory_xy.png`` (top view against ground truth), ``errors_over_time.png`` (position error
    and RPE per frame), ``rpe_cdf.png``."""
    plt = _plt()
    out = []
    n = res.frames
    if n == 0:
        return out
    gt = np.stack(res.T_world_gt[:n]) if res.has_ground_truth else None
    t = (np.asarray(res.stamps_ns[:n], dtype=np.int64) - res.stamps_ns[0]) * 1e-9

    ests = {name: np.stack(res.T_world_est[name][:n]) for name in res.methods}
    cols = 1 + (len(ests) if gt is not None else 0)
    fig, axs = plt.subplots(1, cols, figsize=(7 + 4.2 * (cols - 1), 7 if cols == 1 else 5), squeeze=False)
    ax = axs[0, 0]
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 1, 3], "k--", lw=2, label="ground truth")
    for name, P in ests.items():
        ax.plot(P[:, 0, 3], P[:, 1, 3], lw=1.2, label=name)
    ax.set(xlabel="x [m]", ylabel="y [m]", title="Trajectory (top view)", aspect="equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if gt is not None:  # trajectories that overlap at this scale: the ground-truth path coloured by each error
        errs = {name: np.linalg.norm(P[:, :3, 3] - gt[:, :3, 3], axis=1) for name, P in ests.items()}
        finite = [e[np.isfinite(e)] for e in errs.values()]
        vmax = max([float(e.max()) for e in finite if e.size] + [1e-6])
        for ax, (name, e) in zip(axs[0, 1:], errs.items()):
            sc = ax.scatter(gt[:, 0, 3], gt[:, 1, 3], c=e, cmap="viridis", vmin=0.0, vmax=vmax, s=18)
            worst = float(np.nanmax(e)) if np.isfinite(e).any() else float("nan")
            ax.set(xlabel="x [m]", title=f"{name}: position error\n(max {worst:.3f} m)", aspect="equal")
            ax.grid(alpha=0.3)
        fig.colorbar(sc, ax=list(axs[0, 1:]), label="position error [m] (T_world_0 = ground truth)", shrink=0.8)
    else:
        fig.tight_layout()
    out.append(run / "trajectory_xy.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(3 if gt is not None else 1, 1, figsize=(10, 8 if gt is not None else 3), sharex=True)
    axes = np.atleast_1d(axes)
    for name in res.methods:
        P = np.stack(res.T_world_est[name][:n])
        axes[-1].plot(t, res.runtime_ms[name][:n], lw=0.8, label=name)
        if gt is not None:
            axes[0].plot(t, np.linalg.norm(P[:, :3, 3] - gt[:, :3, 3], axis=1), lw=1, label=name)
            tr, rot = metrics.rpe(P, gt)
            axes[1].plot(t[1:], tr, lw=0.8, label=name)
    if gt is not None:
        axes[0].set(ylabel="position error [m]", title="Error over time (unaligned, T_world_0 = ground truth)")
        axes[1].set(ylabel="RPE translation [m]")
    axes[-1].set(ylabel="runtime [ms/frame]", xlabel="time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
        _legend(ax, fontsize=8)
    fig.tight_layout()
    out.append(run / "errors_over_time.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    if gt is not None:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
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
            _legend(ax)
        fig.tight_layout()
        out.append(run / "rpe_cdf.png")
        fig.savefig(out[-1], dpi=110)
        plt.close(fig)
    return out


__all__ = ["plot_odometry", "plot_pairs", "topic_name"]
