#!/usr/bin/env python3
"""DeepBBS++ from a good start (``register(..., good_start=True)``) against small_gicp GICP, and the wrong starts it
must not accept.

Figures (``good_start.json`` under ``--out``):

* ``timing``: raw pairs of consecutive scans (KITTI sequences under ``--kitti``: real HDL-64E scans; simulated
  drives of every scene in ``--scenes``), each from identity and from the truth moved by ``--noise-trans`` m and
  ``--noise-yaw`` degrees. Per set and method, interleaved pair by pair in this process: small_gicp GICP (``gicp``:
  the GICP anchor node's registration, both raw scans prepared), ``register(T_init)`` (today's pipeline) and
  ``register(T_init, good_start=True)``: p50 / p99 wall ms, p50 / mean CPU ms per pair (this process and its
  children, the network process included: /proc), their ratios to GICP's, the share within 1 deg / 0.3 m and
  which path answered.
* ``wrong_start``: simulated pairs of every scene (and of the KITTI sequences) with starts slid ``--shifts`` m along
  the road (forwards and backwards: corridors of repeated facades, highways), where GICP may settle on a wrong
  pose: per method (``register(T_init)`` and ``good_start``) the cases, the poses accepted (valid) right and wrong
  (valid but more than 1 deg / 0.3 m off), rejected, the share of wrong poses accepted, the paths that answered and
  (``good_start``) why the GICP-first answer was not taken; for GICP alone from the same starts, how often it is
  wrong (it has no verdict: the share the good-start path must catch). ``calibration``: the good-start verdict's
  score (``registration.good_start_*``: a spread subset of the source's GICP voxels) and today's verdict score (the
  sampled points) of every converged GICP-first answer, right and wrong: the highest wrong and lowest right score
  of each, and how many wrong ones reach each threshold.

``good_start.png`` beside it: the ratios to GICP's per set and the wrong poses per scene.

Timings on a shared machine are noisy: the methods run by turns on every pair, so their ratios are fair. Each
call is timed as configured (small_gicp on every core) and a second call, with GICP's solve on one thread
(``registration.exact_gicp``), gives the answer, the same on any machine (``--inexact``: the timed call's). ::

    python scripts/benchmarks/good_start.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --out results/benchmarks
    python scripts/benchmarks/good_start.py --pairs 2 --wrong-pairs 1 --shifts 4 8   # quick (a few minutes)
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from itertools import islice
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

METHODS = ("gicp", "register", "good_start")


def pose_xy_yaw(x: float, y: float, yaw_deg: float) -> np.ndarray:
    T = np.eye(4)
    a = np.radians(yaw_deg)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:2, 3] = (x, y)
    return T


def sim_frames(scene: str, seed: int, n: int, gap: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(raw points, T_world_lidar)] of ``n`` frames ``gap`` apart of a simulated drive (raw sweeps)."""
    from deepbbs_ros.sim.simulator import DriveSimulator

    sim = DriveSimulator(scene, seed, frames=10 + n * gap)
    return [(sim.scan_at(10 + k * gap).points, sim.pose_at(10 + k * gap)) for k in range(n)]


def kitti_frames(folder: Path, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    from deepbbs_ros.datasets import open_source

    return [(np.asarray(s.points, np.float32), np.asarray(s.T_world_lidar)) for s in islice(open_source(folder), n)]


class Runner:
    """The three methods on one config, each call timed (wall and CPU) on every core as configured; with ``exact``
    a second call answers (GICP's solve on one thread: ``registration.exact_gicp``, the GICP baseline on one
    thread), so that every answer is the same on any machine."""

    def __init__(self, config, exact: bool = True) -> None:
        from deepbbs_ros.baselines import SmallGicpRegistration
        from deepbbs_ros.core.registration import DeepBBSRegistration

        self.gicp = SmallGicpRegistration("gicp", config, threads=config.registration.polish_threads)
        self.reg = DeepBBSRegistration(config)
        self.reg.warmup()
        self.answering = (self.gicp, self.reg)
        if exact:
            cfg = config.replace(**{"registration.exact_gicp": True})
            self.answering = (SmallGicpRegistration("gicp", cfg, threads=1), DeepBBSRegistration(cfg))
            self.answering[1].warmup()

    @staticmethod
    def _call(gicp, reg, method: str, src: np.ndarray, tgt: np.ndarray, T0: np.ndarray) -> dict:
        if method == "gicp":
            res = gicp.register(src, tgt, T0)
            return {"T": np.asarray(res.T_target_source), "valid": None, "path": "gicp", "why": ""}
        res = reg.register(src, tgt, T_init=T0, good_start=method == "good_start")
        return {"T": np.asarray(res.T_target_source), "valid": bool(res.valid), "path": res.path,
                "why": reason_kind(res.good_start)}

    def run(self, method: str, src: np.ndarray, tgt: np.ndarray, T0: np.ndarray) -> dict:
        exact = self.answering if self.answering[1] is not self.reg else None
        out, wall, cpu = _common.timed_then_answered(lambda regs: self._call(*regs, method, src, tgt, T0),
                                                     (self.gicp, self.reg), exact)
        return {**out, "ms": wall, "cpu_ms": cpu}

    def close(self) -> None:
        self.reg.close()
        if self.answering[1] is not self.reg:
            self.answering[1].close()


def reason_kind(text: str) -> str:
    """``RegistrationResult.good_start`` in a word: accepted, beyond limits (GICP from the start converged beyond the
    good start's limits, taken by the verdict), coarse to fine (accepted on the second try), or why the first try was
    not taken (verdict, not converged, moved), or the text."""
    if not text.startswith("accepted"):
        text = text.split("; coarse to fine: ")[0]
    for word, kind in (("accepted after coarse to fine", "coarse to fine"), ("accepted, beyond", "beyond limits"),
                       ("accepted, sure, within", "beyond limits"),
                       ("accepted", "accepted"),
                       ("verdict", "verdict"), ("not converged", "not converged"), ("moved", "moved"),
                       ("turned", "moved")):
        if word in text:
            return kind
    return text


def errors(T: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    from deepbbs_ros.metrics import pair_errors

    rot, tr = pair_errors(T, T_gt)
    return float(rot), float(tr)


def timing(runner: Runner, sets: dict, args) -> dict:
    rng = np.random.default_rng(args.seed)
    out = {}
    for name, frames in sets.items():
        rows: dict[str, list[dict]] = {m: [] for m in METHODS}
        for k in range(1, len(frames)):
            (tgt, Pt), (src, Ps) = frames[k - 1], frames[k]
            T_gt = np.linalg.inv(Pt) @ Ps
            starts = {"identity": np.eye(4)}
            phi = rng.uniform(0, 2 * np.pi)
            starts["truth+noise"] = T_gt @ pose_xy_yaw(args.noise_trans * np.cos(phi), args.noise_trans * np.sin(phi),
                                                       args.noise_yaw * rng.choice([-1, 1]))
            for start, T0 in starts.items():
                order = list(METHODS) if (k + len(start)) % 2 else list(reversed(METHODS))  # by turns
                for m in order:
                    r = runner.run(m, src, tgt, T0)
                    rot, tr = errors(r["T"], T_gt)
                    rows[m].append({**r, "start": start, "ok": rot <= 1.0 and tr <= 0.3})
        out[name] = summarise(rows)
        line = ", ".join(f"{m} p50 {s['p50_ms']:.0f} ms ({s.get('p50_vs_gicp', 1):.2f}x) CPU {s['cpu_p50_ms']:.0f} "
                         f"({s.get('cpu_vs_gicp', 1):.2f}x)" for m, s in out[name].items())
        print(f"timing {name}: {line}", flush=True)
    return out


def summarise(rows: dict[str, list[dict]]) -> dict:
    s = {}
    for m, rs in rows.items():
        if not rs:
            continue
        ms, cpu = np.array([r["ms"] for r in rs]), np.array([r["cpu_ms"] for r in rs])
        s[m] = {"pairs": len(rs), "p50_ms": float(np.percentile(ms, 50)), "p99_ms": float(np.percentile(ms, 99)),
                "cpu_p50_ms": float(np.percentile(cpu, 50)), "cpu_mean_ms": float(cpu.mean()),
                "success": float(np.mean([r["ok"] for r in rs])), "paths": dict(Counter(r["path"] for r in rs))}
    g = s.get("gicp")
    if g:
        for v in s.values():
            v["p50_vs_gicp"] = v["p50_ms"] / g["p50_ms"]
            v["p99_vs_gicp"] = v["p99_ms"] / g["p99_ms"]
            v["cpu_vs_gicp"] = v["cpu_p50_ms"] / max(g["cpu_p50_ms"], 1e-9)
            v["cpu_mean_vs_gicp"] = v["cpu_mean_ms"] / max(g["cpu_mean_ms"], 1e-9)
    return s


def gicp_first_scores(reg, src: np.ndarray, tgt: np.ndarray, T0: np.ndarray, T_gt: np.ndarray) -> dict | None:
    """The GICP-first attempt of ``register(..., good_start=True)`` redone step by step (core.polish, core.verdict):
    its answer's good-start verdict score, today's verdict score (sampled points) and whether it is right; None when
    GICP did not converge within the cap or moved too far."""
    import dataclasses

    from deepbbs_ros.core import verdict
    from deepbbs_ros.core.polish import polish

    rc = reg.config.registration
    a, b = reg.preprocess(src), reg.preprocess(tgt)
    cfg = dataclasses.replace(rc, polish_max_iters=rc.good_start_max_iters, polish_max_trans=rc.good_start_max_trans,
                              polish_max_rot_deg=rc.good_start_max_rot_deg)
    pol = polish(a.polish_cloud, b.polish_cloud, T0, cfg)
    if not pol.applied:
        return None
    T = pol.T_target_source
    pts = verdict.spread_subset(a.polish_cloud.points(), rc.good_start_points, rc.polish_voxel or 0.5)
    rot, tr = errors(T, T_gt)
    return {"voxels": verdict.fitness(pts, b.polish_cloud.tree, T, rc.verdict_dist),
            "sampled": verdict.fitness(a.points, b.polish_cloud.tree, T, rc.verdict_dist),
            "right": rot <= 1.0 and tr <= 0.3}


def calibration(scores: list[dict], rc) -> dict:
    out = {"converged": len(scores), "right": sum(s["right"] for s in scores)}
    # the fitness thresholds the verdict had before its calibrated probability (0.65 voxels, 0.35 sampled points)
    for kind, thr in (("voxels", 0.65), ("sampled", rc.verdict_threshold)):
        wrong = [s[kind] for s in scores if not s["right"]]
        right = [s[kind] for s in scores if s["right"]]
        out[kind] = {"threshold": thr, "wrong_max": max(wrong, default=float("nan")),
                     "right_min": min(right, default=float("nan")), "wrong_accepted": sum(w >= thr for w in wrong),
                     "right_rejected": sum(r < thr for r in right)}
    return out


def wrong_starts(runner: Runner, sets: dict, args) -> dict:
    out: dict = {}
    scores: list[dict] = []
    total: dict[str, Counter] = {m: Counter() for m in METHODS}
    for scene, frames in sets.items():
        per: dict[str, Counter] = {m: Counter() for m in METHODS}
        for k in range(1, len(frames)):
            (tgt, Pt), (src, Ps) = frames[k - 1], frames[k]
            T_gt = np.linalg.inv(Pt) @ Ps
            for d in args.shifts:
                for sign in (1, -1):
                    T0 = T_gt.copy()
                    T0[:3, 3] += sign * d * T0[:3, 0]  # slid along the road: the sensor's heading (x)
                    s = gicp_first_scores(runner.answering[1], src, tgt, T0, T_gt)
                    if s is not None:
                        scores.append(s)
                    for m in METHODS:
                        r = runner.run(m, src, tgt, T0)
                        rot, tr = errors(r["T"], T_gt)
                        right = rot <= 1.0 and tr <= 0.3
                        c = per[m]
                        c["cases"] += 1
                        if m == "gicp":  # no verdict: right or wrong
                            c["right" if right else "wrong"] += 1
                            continue
                        c["accepted_right" if r["valid"] and right else "accepted_wrong" if r["valid"] else
                          "rejected"] += 1
                        c[f"path_{r['path']}"] += 1
                        if m == "good_start":
                            c[f"why_{r['why']}"] += 1
        out[scene] = {m: finish(c) for m, c in per.items()}
        for m in per:
            total[m].update(per[m])
        g = out[scene]["gicp"]
        print(f"wrong starts {scene}: gicp alone {g['wrong']} wrong of {g['cases']}; " + "; ".join(
            f"{m} {v['accepted_wrong']} wrong / {v['accepted_right']} right / {v['rejected']} rejected of {v['cases']}"
            for m, v in out[scene].items() if m != "gicp"), flush=True)
    out["all"] = {m: finish(c) for m, c in total.items()}
    out["calibration"] = calibration(scores, runner.answering[1].config.registration)
    print(f"calibration: {out['calibration']}", flush=True)
    return out


def finish(c: Counter) -> dict:
    if "right" in c or "wrong" in c:  # GICP alone
        d = {k: int(c.get(k, 0)) for k in ("cases", "right", "wrong")}
        d["wrong_share"] = d["wrong"] / d["cases"] if d["cases"] else float("nan")
        return d
    d = {k: int(c.get(k, 0)) for k in ("cases", "accepted_right", "accepted_wrong", "rejected")}
    d["wrong_accepted_share"] = d["accepted_wrong"] / d["cases"] if d["cases"] else float("nan")
    d["paths"] = {k.removeprefix("path_"): int(v) for k, v in c.items() if k.startswith("path_")}
    why = {k.removeprefix("why_"): int(v) for k, v in c.items() if k.startswith("why_")}
    if why:
        d["good_start"] = why  # why the GICP-first answer was (not) taken
    return d


def plot(figures: dict, out: Path) -> Path | None:
    """``out``/good_start.png: per data set the p50, p99 and mean CPU of ``register(T_init)`` and of the good start
    as ratios to GICP's (left, the 1.1 goal drawn in), and per scene the wrong poses: GICP alone's, and those each
    method accepted (right)."""
    timing_, wrong = figures.get("timing") or {}, figures.get("wrong_start") or {}
    if not timing_ and not wrong:
        return None
    plt = _common.pyplot()
    f, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    sets = list(timing_)
    bars = [(m, key, label) for m in ("register", "good_start")
            for key, label in (("p50_vs_gicp", "p50"), ("p99_vs_gicp", "p99"), ("cpu_mean_vs_gicp", "CPU"))]
    width = 0.8 / len(bars)
    for j, (m, key, label) in enumerate(bars):
        x = np.arange(len(sets)) + (j - (len(bars) - 1) / 2) * width
        a.bar(x, [(timing_[s].get(m) or {}).get(key) or np.nan for s in sets], width * 0.95,
              color=f"C{j % 3}", alpha=0.45 if m == "register" else 1.0,
              label=f"{'register(T_init)' if m == 'register' else 'good_start=True'} {label}")
    a.axhline(1.0, color="k", lw=0.6)
    a.axhline(1.1, color="k", lw=0.8, ls=":")
    a.set_xticks(np.arange(len(sets)), [s.replace("sim_", "") for s in sets], fontsize=8)
    a.set_ylabel("x small_gicp GICP's")
    a.set_title("time and CPU per raw pair against GICP (goal 1.1)")
    a.legend(fontsize=6, ncol=2)
    scenes = [s for s in wrong if s not in ("all", "calibration")]
    for j, (m, key, label) in enumerate((("gicp", "wrong", "GICP alone: wrong"),
                                         ("register", "accepted_wrong", "register(T_init): wrong accepted"),
                                         ("good_start", "accepted_wrong", "good_start=True: wrong accepted"))):
        x = np.arange(len(scenes)) + (j - 1) * 0.27
        b.bar(x, [(wrong[s].get(m) or {}).get(key) or 0 for s in scenes], 0.26, color=f"C{j + 3}", label=label)
    b.set_xticks(np.arange(len(scenes)), scenes, fontsize=8)
    b.set_ylabel(f"poses, of {max(((wrong[s].get('gicp') or {}).get('cases') or 0) for s in scenes or [None])} "
                 "starts per scene" if scenes else "poses")
    b.set_title(f"starts slid along the road ({', '.join(f'{d:g}' for d in figures.get('shifts_m', []))} m)")
    b.legend(fontsize=7)
    return _common.save(f, out, "good_start.png")


def main(argv: list[str] | None = None) -> int:
    from deepbbs_ros.sim.scene import SCENES

    p = argparse.ArgumentParser(description="DeepBBS++ from a good start vs small_gicp GICP; wrong starts along "
                                "roads (see the module docstring).")
    g = p.add_argument_group("timing (consecutive scans)")
    g.add_argument("--kitti", type=Path, nargs="*", default=[], help="KITTI odometry sequence folders (real scans)")
    g.add_argument("--kitti-scans", type=int, default=10, help="the first scans of each KITTI sequence")
    g.add_argument("--pairs", type=int, default=25, help="consecutive pairs per simulated scene (each timed twice: "
                   "a p99 and a CPU mean over 50 calls, not a maximum of a dozen)")
    g.add_argument("--noise-trans", type=float, default=0.2, help="m; the truth moved by this for the noisy start")
    g.add_argument("--noise-yaw", type=float, default=1.0, help="deg; and turned by this")
    g = p.add_argument_group("wrong starts (simulated roads)")
    g.add_argument("--wrong-pairs", type=int, default=3, help="pairs per scene")
    g.add_argument("--wrong-gap", type=int, default=3, help="frames between source and target")
    g.add_argument("--shifts", type=float, nargs="+", default=[2.0, 4.0, 6.0, 8.0, 10.0],
                   help="m; starts slid this far along the road, forwards and backwards")
    g = p.add_argument_group("run")
    g.add_argument("--scenes", nargs="+", default=list(SCENES), choices=SCENES, help="simulated scenes")
    g.add_argument("--seed", type=int, default=3, help="simulated drives and start noise")
    g.add_argument("--skip", choices=("timing", "wrong"), default=None, help="leave one part out")
    g.add_argument("--config", help="config YAML (DeepBBS++ and GICP's eval.baseline_* keys)")
    g.add_argument("--out", type=Path, default=Path("results/benchmarks"), help="folder of good_start.json")
    g.add_argument("--inexact", action="store_true", help="the timed call answers too (default: a second call with "
                   "GICP's solve on one thread answers: the same answers on any machine)")
    args = p.parse_args(argv)

    from deepbbs_ros.config import Config

    config = Config.from_yaml(args.config) if args.config else Config()
    runner = Runner(config, exact=not args.inexact)
    figures: dict = {"noise": {"trans_m": args.noise_trans, "yaw_deg": args.noise_yaw}, "shifts_m": args.shifts}
    kitti = {f"kitti_{k.name}": kitti_frames(k, args.kitti_scans) for k in args.kitti}
    if args.skip != "timing":
        sets = {**kitti, **{f"sim_{s}": sim_frames(s, args.seed, args.pairs + 1) for s in args.scenes}}
        figures["timing"] = timing(runner, sets, args)
    if args.skip != "wrong":
        gap = args.wrong_gap
        sets = {s: sim_frames(s, args.seed + 1, args.wrong_pairs + 1, gap=gap) for s in args.scenes}
        sets.update({k: v[::gap][: args.wrong_pairs + 1] for k, v in kitti.items()})
        figures["wrong_start"] = wrong_starts(runner, sets, args)
    runner.close()
    _common.write_json(args.out, "good_start.json", figures)
    plot(figures, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
