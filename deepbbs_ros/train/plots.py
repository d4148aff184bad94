"""Training curves from ``log.jsonl`` (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def _smooth(y: np.ndarray, w: int) -> np.ndarray:
    if len(y) < 2 or w <= 1:
        return y
    w = min(w, len(y))
    c = np.cumsum(np.insert(y, 0, 0.0))
    head = c[1:w] / np.arange(1, w)
    return np.concatenate([head, (c[w:] - c[:-w]) / w])


def plot_curves(log_path: str | Path, out_path: str | Path) -> Path:
    """Four panels: training loss terms (smoothed, log scale) with the validation loss; validation
    rotation error (deg) and translation error (m), with and without extra yaw; success rate (%)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    train, val = [], []
    for ln in Path(log_path).read_text().splitlines():
        if not ln.strip():
            continue
        rec = json.loads(ln)
        (val if rec.get("kind") == "val" else train).append(rec)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    ax = axes[0, 0]
    if train:
        steps = np.array([r["step"] for r in train])
        w = max(1, len(train) // 50)
        terms = (("loss", "total"), ("rot", "rotation"), ("trans", "translation"), ("corr", "correspondence"))
        for key, label in terms:
            y = np.array([r[key] for r in train], dtype=np.float64)
            ax.plot(steps, np.maximum(_smooth(y, w), 1e-9), label=f"train {label}", lw=1)
    if val:
        ax.plot([v["step"] for v in val], [v["val_loss"] for v in val], "ko-", ms=3, label="validation (one pass)")
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss (scaled units)")
    ax.set_title("loss")
    ax.legend(fontsize=7)
    titles = (("rot_mean_deg", "mean rotation error (deg)", axes[0, 1]),
              ("trans_mean_m", "mean translation error (m)", axes[1, 0]),
              ("success", "success rate (%)", axes[1, 1]))
    for key, title, ax in titles:
        for split, style in (("plain", "o-"), ("yaw", "s--")):
            xs = [v["step"] for v in val]
            ys = [v[split][key] * (100 if key == "success" else 1) for v in val]
            label = "held-out pairs" if split == "plain" else "held-out pairs + random yaw"
            if xs:
                ax.plot(xs, ys, style, ms=3, label=label)
        if key != "success" and val:
            ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_title(f"validation: {title} (DeepBBS++)")
        ax.grid(alpha=0.3)
        if val:
            ax.legend(fontsize=7)
    fig.tight_layout()
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=90)
    plt.close(fig)
    return out_path
