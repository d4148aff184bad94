"""Replay plots stay readable: top views of straight and curvy drives (no strip axes, tick labels apart, the
legend off the data), error panels whose scales show every method, zeros on log axes."""

from __future__ import annotations

import numpy as np
import pytest

from deepbbs_ros.replay import plots as P

pytest.importorskip("matplotlib")


def _poses(xy: np.ndarray, yaw: np.ndarray | None = None) -> np.ndarray:
    T = np.tile(np.eye(4), (len(xy), 1, 1))
    T[:, :2, 3] = xy
    if yaw is not None:
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    return T


def _straight(n=60, origin=(0.0, 0.0)):
    """A straight drive along x (1 m per frame), estimates drifting a few cm sideways, one diverging."""
    gt = _poses(np.c_[np.arange(n, dtype=float), np.zeros(n)] + origin)
    ests = {}
    for k, drift in enumerate((0.002, 0.001, 0.08)):
        est = gt.copy()
        est[:, 1, 3] += drift * np.arange(n)
        est[:, 0, 3] += 0.01 * k * np.arange(n)
        ests[["deepbbs++", "kiss-icp", "gicp"][k]] = est
    return gt, ests


def _curvy(n=80):
    """Straight 40 m north, then a 90-degree left turn of radius 20 m."""
    s = np.linspace(0.0, 40.0 + np.pi * 10.0, n)
    xy, yaw = np.zeros((n, 2)), np.zeros(n)
    line = s <= 40.0
    xy[line] = np.c_[np.zeros(line.sum()), s[line]]
    yaw[line] = np.pi / 2
    a = (s[~line] - 40.0) / 20.0
    xy[~line] = np.c_[-20.0 + 20.0 * np.cos(a), 40.0 + 20.0 * np.sin(a)]
    yaw[~line] = np.pi / 2 + a
    gt = _poses(xy, yaw)
    est = gt.copy()
    est[:, :2, 3] += 0.01 * np.arange(n)[:, None]
    return gt, {"gicp": est}


def _boxes(fig):
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _tick_labels(ax, axis, renderer):
    lo, hi = sorted(getattr(ax, f"get_{axis}lim")())
    ticks = getattr(ax, f"get_{axis}axis")().get_major_ticks()
    return [t.label1.get_window_extent(renderer) for t in ticks
            if t.label1.get_visible() and t.label1.get_text() and lo <= t.get_loc() <= hi]


def _check_readable(fig, axes):
    """No axes is a strip, tick labels do not run into each other, the legend covers no axes."""
    r = _boxes(fig)
    for ax in axes:
        box = ax.get_window_extent(r)
        assert box.height >= 0.5 * box.width and box.width >= 0.5 * box.height, (ax.get_title(), box)
        for axis in "xy":
            labels = _tick_labels(ax, axis, r)
            assert len(labels) >= 3, (ax.get_title(), axis)
            assert not any(a.overlaps(b) for i, a in enumerate(labels) for b in labels[i + 1:]), (ax.get_title(), axis)
            assert all(len(t.get_text()) <= 7 for t in getattr(ax, f"get_{axis}ticklabels")())
    (legend,) = fig.legends
    lbox = legend.get_window_extent(r)
    for ax in fig.axes:
        assert not lbox.overlaps(ax.get_window_extent(r)), ax.get_title()


def test_straight_drive_top_view_is_readable():
    gt, ests = _straight()
    fig = P.trajectory_figure(ests, gt)
    tops = [ax for ax in fig.axes if ax.get_xlabel().startswith("x")]
    assert len(tops) == 4  # the trajectories, then one error panel per method
    _check_readable(fig, tops)
    for ax in tops:  # drawn stretched, and it says so; the short axis padded to a quarter of the long one
        assert "not to scale: y stretched" in ax.get_title() and ax.get_aspect() == "auto"
        assert np.ptp(ax.get_ylim()) == pytest.approx(P.STRETCHED_XY_RATIO * np.ptp(ax.get_xlim()), rel=0.15)
    # each error panel has its own colour scale: the diverged method does not flatten the others
    bars = [ax for ax in fig.axes if ax.get_xlabel().startswith("position error")]
    assert len(bars) == 3 and bars[0].get_xlim()[1] < 0.2 < bars[2].get_xlim()[1]


def test_curvy_drive_top_view_is_to_scale():
    gt, ests = _curvy()
    fig = P.trajectory_figure(ests, gt)
    tops = [ax for ax in fig.axes if ax.get_xlabel().startswith("x")]
    _check_readable(fig, tops)
    for ax in tops:
        assert ax.get_aspect() == 1.0 and "not to scale" not in ax.get_title()
        lo, hi = ax.get_xlim()
        assert lo <= gt[:, 0, 3].min() and gt[:, 0, 3].max() <= hi


def test_map_coordinates_are_plotted_from_the_start():
    """UTM-sized coordinates: axes relative to the first ground-truth position, short tick labels, no offset text."""
    gt, ests = _straight(origin=(587012.25, 4141234.5))
    fig = P.trajectory_figure(ests, gt)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "x - 587012 [m]" and ax.get_ylabel() == "y - 4141234 [m]"
    _check_readable(fig, [a for a in fig.axes if a.get_xlabel().startswith("x")])
    assert ax.xaxis.get_offset_text().get_text() == "" and ax.yaxis.get_offset_text().get_text() == ""


def test_error_panels_show_every_method():
    gt, ests = _straight()
    t = np.arange(len(gt)) * 0.1
    runtime = {name: np.full(len(gt), 20.0) for name in ests}
    fig = P.errors_over_time_figure(t, ests, runtime, gt)
    r = _boxes(fig)
    pos, rpe, rt = fig.axes[:3]
    assert pos.get_yscale() == "log"  # gicp drifts 100x the others: a log scale keeps them readable
    assert rt.get_yscale() == "linear" and rt.get_ylim()[0] == 0.0
    lbox = fig.legends[0].get_window_extent(r)
    assert not any(lbox.overlaps(ax.get_window_extent(r)) for ax in fig.axes)
    close = {k: v for k, v in ests.items() if k != "gicp"}
    fig = P.errors_over_time_figure(t, close, runtime, gt)
    assert fig.axes[0].get_yscale() == "linear" and fig.axes[0].get_ylim()[0] == 0.0


def test_pair_plots_legend_off_the_data_and_zero_errors(tmp_path):
    from deepbbs_ros.replay.runner import PairRecord, PairResults

    res = PairResults(["deepbbs++", "gicp"])
    eye = np.eye(4)
    for k in range(8):
        for name, scale in (("deepbbs++", 1.0), ("gicp", 3.0)):
            rot = 0.0 if k == 7 else 0.05 * scale * (k + 1)  # an exact zero: a log axis cannot show it
            res.records.append(PairRecord(name, k, 0, k, k + 1, k, k + 1, "lidar", 1.0, eye, eye, eye, rot,
                                          0.02 * scale * (k + 1), True, 10.0, 1.0, True))
    import matplotlib.image as mpimg

    paths = P.plot_pairs(tmp_path, res, 1.0, 0.3)
    assert [p.name for p in paths] == ["errors_cdf.png", "errors_hist.png", "errors_over_pairs.png"]
    for p in paths:
        assert mpimg.imread(p).shape[0] > 300
    # the same figures, drawn again to inspect them
    import matplotlib.pyplot as plt

    figs = []
    orig = plt.close
    try:
        plt.close = figs.append  # keep each figure open
        P.plot_pairs(tmp_path, res, 1.0, 0.3)
    finally:
        plt.close = orig
    for fig in figs:
        r = _boxes(fig)
        (legend,) = fig.legends
        assert not any(legend.get_window_extent(r).overlaps(ax.get_window_extent(r)) for ax in fig.axes)
        plt.close(fig)
    over_pairs = figs[2].axes[0]
    assert "an error of 0 is drawn at 0.0001" in over_pairs.get_title()
    assert over_pairs.get_ylim()[0] <= P.ZERO_FLOOR


def test_save_ends_a_figure_the_same_way_everywhere(tmp_path):
    """plot_style.save: a grid on the axes asked, one figure legend from several panels (each label once), the PNG
    at DPI, the figure closed, the path appended."""
    import matplotlib.image as mpimg

    from deepbbs_ros.replay import plot_style as S

    plt = S.pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(4, 3), layout="constrained")
    for ax in axes:
        ax.plot([0, 1], [0, 1], label="shared")
    axes[1].plot([0, 1], [1, 0], label="second only")
    kept = []
    orig = plt.close
    try:
        plt.close = kept.append  # keep the figure to inspect it
        paths: list = []
        assert S.save(fig, tmp_path / "f.png", paths, grid=axes[:1], legend=axes) == tmp_path / "f.png"
    finally:
        plt.close = orig
    assert paths == [tmp_path / "f.png"] and kept == [fig]
    assert mpimg.imread(paths[0]).shape[:2] == (3 * S.DPI, 4 * S.DPI)
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["shared", "second only"]
    assert axes[0].xaxis.get_gridlines()[0].get_visible() and not axes[1].xaxis.get_gridlines()[0].get_visible()
    plt.close(fig)
