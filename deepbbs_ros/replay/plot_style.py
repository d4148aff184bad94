"""What every replay plot shares: matplotlib on the Agg backend, CDF curves, log axes (or a note when the values do not
allow one), the figure legend, how a figure ends (grid, legend, PNG), tick locators, and the top view's frame (to scale
or stretched) and axes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: every replay PNG is written at this resolution, dots per inch
DPI = 110


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def cdf(ax, values, label):
    v = np.asarray(values, dtype=np.float64)
    v = np.sort(v[np.isfinite(v)])
    if v.size:
        ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=label)


def finite_positive(values) -> bool:
    v = np.asarray(values, dtype=np.float64)
    return bool(np.any(np.isfinite(v) & (v > 0)))


def log_or_note(ax, axis: str, values) -> None:
    """Log scale on ``axis`` when some value is finite and > 0, else a linear axis and a note saying
    why it is empty (every registration failed, or an exact zero error)."""
    if finite_positive(values):
        (ax.set_xscale if axis == "x" else ax.set_yscale)("log")
    else:
        ax.text(0.5, 0.5, "no finite error > 0 to plot", transform=ax.transAxes, ha="center", va="center",
                color="0.4")


def figure_legend(fig, *axes, ncol: int = 6) -> None:
    """One legend for the whole figure, above its panels (never on the data), from the labelled lines of ``axes``
    (a label several panels share, once), at most ``ncol`` entries a row."""
    handles, labels = [], []
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(handle)
                labels.append(label)
    if labels:
        fig.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), ncol), fontsize=9, frameon=False)


def finish(fig, grid=(), legend=(), ncol: int = 6) -> None:
    """End a figure: a light grid on each axes of ``grid``, one :func:`figure_legend` from the axes of ``legend``."""
    for ax in grid:
        ax.grid(alpha=0.3)
    figure_legend(fig, *legend, ncol=ncol)


def save(fig, path: Path, paths: list[Path] | None = None, *, grid=(), legend=(), ncol: int = 6) -> Path:
    """:func:`finish` ``fig``, write it to ``path`` (PNG at :data:`DPI`), close it and append ``path`` to ``paths``."""
    finish(fig, grid, legend, ncol)
    path = Path(path)
    fig.savefig(path, dpi=DPI)
    pyplot().close(fig)
    if paths is not None:
        paths.append(path)
    return path


#: errors of exactly 0 (a log axis cannot show them) are drawn at this floor, deg or m
ZERO_FLOOR = 1e-4


def on_log_axis(values) -> tuple[np.ndarray, bool]:
    """(values with exact zeros raised to :data:`ZERO_FLOOR`, whether any was)."""
    v = np.asarray(values, dtype=np.float64)
    zero = v == 0.0
    return np.where(zero, ZERO_FLOOR, v), bool(zero.any())


#: a top view is drawn to scale (a square panel, the short axis padded) while the path's short extent is at least
#: this share of its long one; a flatter path (a straight drive) is drawn not to scale, its short axis padded to
#: STRETCHED_XY_RATIO of the long one, so that its lateral errors stay visible
MIN_XY_RATIO = 0.1
STRETCHED_XY_RATIO = 0.25
#: coordinates this large (UTM, map frames) are plotted relative to the first ground-truth position
BIG_COORD = 1e4


def xy_frame(paths: list[np.ndarray]) -> tuple[np.ndarray, tuple, tuple, bool]:
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


def xy_axes(ax, origin: np.ndarray, xlim: tuple, ylim: tuple, to_scale: bool, title: str) -> None:
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


def ticks(n: int, integer: bool = False):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(nbins=n, integer=integer)


