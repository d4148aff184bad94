"""The figures of registration.py: the protocols' names and moves, the methods' labels, the summary of the cases
(success, errors, p50 / p95 times and their ratios to GICP's, the verdict), its printout and its plots."""

from __future__ import annotations

from pathlib import Path

import _common
import numpy as np

PROTOCOLS = {"as-they-come": (0.0, 0.0), "45deg-5m": (45.0, 5.0), "any-start": (180.0, 10.0)}
LABELS = {"deepbbs++": "DeepBBS++ (shipped)", "deepbbs++paper": "DeepBBS++ paper (no GICP)",
          "deepbbs++fast": "DeepBBS++ fast preset", "deepbbs++local": "DeepBBS++ without global search",
          "gicp": "small_gicp GICP", "kiss-matcher": "KISS-Matcher", "kiss-matcher+gicp": "KISS-Matcher + GICP"}


def group(name: str) -> str:
    return name.split("_")[0]  # kitti, pair, sim


def summarise(recs: list[dict], names: list[str]) -> dict:
    def cell(sel: list[dict], m: str, anchor_p50: float | None) -> dict | None:
        rs = [r[m] for r in sel if m in r]
        if not rs:
            return None
        ok = [x for x in rs if x["ok"]]
        ms = np.array([x["ms"] for x in rs])
        p50 = float(np.median(ms))
        return {"cases": len(rs), "success_pct": 100.0 * len(ok) / len(rs),
                "rot_deg_mean": float(np.mean([x["rot"] for x in ok])) if ok else None,
                "trans_m_mean": float(np.mean([x["trans"] for x in ok])) if ok else None,
                "p50_ms": p50, "p95_ms": float(np.percentile(ms, 95)),
                "p50_over_gicp": p50 / anchor_p50 if anchor_p50 else None}

    out: dict = {"protocols": {}}
    groups = {"real": ("kitti", "pair"), "kitti": ("kitti",), "pair": ("pair",), "sim": ("sim",),
              "all": ("kitti", "pair", "sim")}
    for proto in PROTOCOLS:
        out["protocols"][proto] = {}
        for g, members in groups.items():
            sel = [r for r in recs if r["protocol"] == proto and group(r["set"]) in members]
            gicp = [r["gicp"]["ms"] for r in sel if "gicp" in r]
            anchor = float(np.median(gicp)) if gicp else None
            cells = {m: cell(sel, m, anchor) for m in names}
            cells = {m: c for m, c in cells.items() if c}
            km = cells.get("kiss-matcher+gicp")
            # the speed against KISS-Matcher + GICP on the cases it ran (every n-th one): both p50s over those cases
            both = [r for r in sel if "kiss-matcher+gicp" in r]
            km_p50 = float(np.median([r["kiss-matcher+gicp"]["ms"] for r in both])) if km and both else None
            for m, c in cells.items():
                same = [r[m]["ms"] for r in both if m in r]
                c["p50_over_kiss_matcher_gicp"] = float(np.median(same)) / km_p50 if km_p50 and same else None
            if cells:
                out["protocols"][proto][g] = cells
    true = [r for r in recs if r["kind"] == "true"]
    verdict: dict = {}
    for m in ("deepbbs++", "deepbbs++local"):
        rs = [r[m] for r in true if m in r]
        if not rs:
            continue
        good = [x for x in rs if x["ok"]]
        wrong = [x for x in rs if not x["ok"]]
        verdict[m] = {"correct": len(good), "correct_accepted_pct": 100.0 * np.mean([x["valid"] for x in good])
                      if good else None, "wrong": len(wrong),
                      "wrong_rejected_pct": 100.0 * np.mean([not x["valid"] for x in wrong]) if wrong else None,
                      "lowest_correct_score": min((x["score"] for x in good), default=None),
                      "highest_wrong_score": max((x["score"] for x in wrong), default=None)}
    diff = [r["deepbbs++"] for r in recs if r["kind"] == "different" and "deepbbs++" in r]
    if diff:
        verdict["different_places"] = {"pairs": len(diff),
                                       "rejected_pct": 100.0 * np.mean([not x["valid"] for x in diff]),
                                       "highest_score": max(x["score"] for x in diff),
                                       "p50_ms": float(np.median([x["ms"] for x in diff]))}
    out["verdict"] = verdict
    return out


def report(fig: dict, names: list[str]) -> None:
    for proto, groups in fig["protocols"].items():
        print(f"\n{proto}: success %, mean rot deg / trans m of the successes, p50 / p95 ms, p50 / GICP p50")
        for g, cells in groups.items():
            for m, c in cells.items():
                err = "-" if c["rot_deg_mean"] is None else f"{c['rot_deg_mean']:.3f} / {c['trans_m_mean']:.3f}"
                ratio = "-" if c["p50_over_gicp"] is None else f"{c['p50_over_gicp']:.2f}"
                print(f"  {g:>5} {m:>18}: {c['success_pct']:5.1f} % ({c['cases']:3d})  {err:>15}  "
                      f"{c['p50_ms']:6.0f} / {c['p95_ms']:6.0f} ms  x{ratio}")
    for k, v in fig["verdict"].items():
        print(f"verdict, {k}: {v}")


def plot(fig: dict, recs: list[dict], names: list[str], out: Path) -> None:
    plt = _common.pyplot()
    f, axes = plt.subplots(1, 3, figsize=(16, 4.6))
    protos = list(PROTOCOLS)
    w = 0.8 / max(1, len(names))
    for ax, g in zip(axes[:2], ("real", "sim")):
        for k, m in enumerate(names):
            v = [(fig["protocols"][p].get(g, {}).get(m) or {}).get("success_pct", np.nan) for p in protos]
            ax.bar(np.arange(len(protos)) + k * w, v, w, label=LABELS[m])
        ax.set_xticks(np.arange(len(protos)) + 0.4 - w / 2, protos)
        ax.set_ylim(0, 105)
        ax.set_ylabel("success % (within 1 deg / 0.3 m)")
        ax.set_title(f"{g} pairs")
        ax.grid(axis="y", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    f.legend(handles, labels, loc="upper center", ncol=len(names), fontsize=8, bbox_to_anchor=(0.5, 0.0))
    ax = axes[2]
    for k, m in enumerate(names):
        v = [(fig["protocols"][p].get("all", {}).get(m) or {}).get("p50_ms", np.nan) for p in protos]
        bars = ax.bar(np.arange(len(protos)) + k * w, v, w, label=LABELS[m])
        for b, p in zip(bars, protos):
            c = fig["protocols"][p].get("all", {}).get(m)
            if c and c["p50_over_gicp"]:
                ax.annotate(f"{c['p50_over_gicp']:.1f}x", (b.get_x() + b.get_width() / 2, b.get_height()),
                            ha="center", va="bottom", fontsize=6)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(protos)) + 0.4 - w / 2, protos)
    ax.set_ylabel("p50 ms per raw pair (label: x GICP's p50)")
    ax.set_title("time, all pairs")
    ax.grid(axis="y", alpha=0.3)
    _common.save(f, out, "registration.png")

    f, ax = plt.subplots(figsize=(7, 4))
    bins = np.linspace(0, 1, 51)
    true = [r for r in recs if r["kind"] == "true"]
    for label, v in (("correct results", [r[m]["score"] for r in true for m in ("deepbbs++", "deepbbs++local")
                                          if m in r and r[m]["ok"]]),
                     ("wrong poses", [r[m]["score"] for r in true for m in ("deepbbs++", "deepbbs++local")
                                      if m in r and not r[m]["ok"]]),
                     ("different places", [r["deepbbs++"]["score"] for r in recs
                                           if r["kind"] == "different" and "deepbbs++" in r])):
        if v:
            ax.hist(v, bins, alpha=0.6, label=f"{label} ({len(v)})")
    from deepbbs_ros.config import Config

    ax.axvline(Config().registration.verdict_threshold, color="k", ls="--", label="registration.verdict_threshold")
    ax.set_xlabel("result.score (share of sampled source points within 0.5 m of the target)")
    ax.set_ylabel("registrations")
    ax.legend(fontsize=8)
    _common.save(f, out, "verdict.png")
