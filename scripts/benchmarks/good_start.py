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
* ``wrong_start``: simulated pairs of every scene with starts slid ``--shifts`` m along the road (forwards and
  backwards: corridors of repeated facades, highways), where GICP may settle on a wrong pose: per method
  (``register(T_init)`` and ``good_start``) the cases, the poses accepted (valid) right and wrong (valid but more
  than 1 deg / 0.3 m off), rejected, the share of wrong poses accepted, and the paths that answered.

Timings on a shared machine are noisy: the methods run by turns on every pair, so their ratios are fair. ::

    python scripts/benchmarks/good_start.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --out results/benchmarks
    python scripts/benchmarks/good_start.py --pairs 2 --wrong-pairs 1 --shifts 4 8   # quick (a few minutes)
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from itertools import islice
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

METHODS = ("gicp", "register", "good_start")


def cpu_seconds() -> float:
    """CPU seconds (user + system) of this process and every process below it (Linux /proc; elsewhere this
    process only)."""
    if not Path("/proc/self/task").is_dir():
        return time.process_time()
    tick = os.sysconf("SC_CLK_TCK")
    total, todo, seen = 0.0, [os.getpid()], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                f = (task / "stat").read_text().rsplit(")", 1)[1].split()
                total += (int(f[11]) + int(f[12])) / tick
                todo += [int(c) for c in (task / "children").read_text().split()]
            except (OSError, ValueError):
                continue
    return total


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
    """The three methods on one config, each call timed (wall and CPU)."""

    def __init__(self, config) -> None:
        from deepbbs_ros.baselines import SmallGicpRegistration
        from deepbbs_ros.core.registration import DeepBBSRegistration

        self.gicp = SmallGicpRegistration("gicp", config, threads=config.registration.polish_threads)
        self.reg = DeepBBSRegistration(config)
        self.reg.warmup()

    def run(self, method: str, src: np.ndarray, tgt: np.ndarray, T0: np.ndarray) -> dict:
        c0, t0 = cpu_seconds(), time.perf_counter()
        if method == "gicp":
            res = self.gicp.register(src, tgt, T0)
            valid, path = None, "gicp"
        else:
            res = self.reg.register(src, tgt, T_init=T0, good_start=method == "good_start")
            valid, path = bool(res.valid), res.path
        wall, cpu = (time.perf_counter() - t0) * 1e3, (cpu_seconds() - c0) * 1e3
        return {"T": np.asarray(res.T_target_source), "valid": valid, "path": path, "ms": wall, "cpu_ms": cpu}


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


def wrong_starts(runner: Runner, args) -> dict:
    out: dict = {}
    total: dict[str, Counter] = {m: Counter() for m in ("register", "good_start")}
    for scene in args.scenes:
        frames = sim_frames(scene, args.seed + 1, args.wrong_pairs + 1, gap=args.wrong_gap)
        per: dict[str, Counter] = {m: Counter() for m in ("register", "good_start")}
        for k in range(1, len(frames)):
            (tgt, Pt), (src, Ps) = frames[k - 1], frames[k]
            T_gt = np.linalg.inv(Pt) @ Ps
            for d in args.shifts:
                for sign in (1, -1):
                    T0 = T_gt.copy()
                    T0[:3, 3] += sign * d * T0[:3, 0]  # slid along the road: the sensor's heading (x)
                    for m in ("register", "good_start"):
                        r = runner.run(m, src, tgt, T0)
                        rot, tr = errors(r["T"], T_gt)
                        right = rot <= 1.0 and tr <= 0.3
                        c = per[m]
                        c["cases"] += 1
                        c["accepted_right" if r["valid"] and right else "accepted_wrong" if r["valid"] else
                          "rejected"] += 1
                        c[f"path_{r['path']}"] += 1
        out[scene] = {m: finish(c) for m, c in per.items()}
        for m in per:
            total[m].update(per[m])
        print(f"wrong starts {scene}: " + "; ".join(
            f"{m} {v['accepted_wrong']} wrong / {v['accepted_right']} right / {v['rejected']} rejected of {v['cases']}"
            for m, v in out[scene].items()), flush=True)
    out["all"] = {m: finish(c) for m, c in total.items()}
    return out


def finish(c: Counter) -> dict:
    d = {k: int(c.get(k, 0)) for k in ("cases", "accepted_right", "accepted_wrong", "rejected")}
    d["wrong_accepted_share"] = d["accepted_wrong"] / d["cases"] if d["cases"] else float("nan")
    d["paths"] = {k.removeprefix("path_"): int(v) for k, v in c.items() if k.startswith("path_")}
    return d


def main(argv: list[str] | None = None) -> int:
    from deepbbs_ros.sim.scene import SCENES

    p = argparse.ArgumentParser(description="DeepBBS++ from a good start vs small_gicp GICP; wrong starts along "
                                "roads (see the module docstring).")
    g = p.add_argument_group("timing (consecutive scans)")
    g.add_argument("--kitti", type=Path, nargs="*", default=[], help="KITTI odometry sequence folders (real scans)")
    g.add_argument("--kitti-scans", type=int, default=10, help="the first scans of each KITTI sequence")
    g.add_argument("--pairs", type=int, default=6, help="consecutive pairs per simulated scene")
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
    args = p.parse_args(argv)

    from deepbbs_ros.config import Config

    config = Config.from_yaml(args.config) if args.config else Config()
    runner = Runner(config)
    figures: dict = {"noise": {"trans_m": args.noise_trans, "yaw_deg": args.noise_yaw}, "shifts_m": args.shifts}
    if args.skip != "timing":
        sets = {f"kitti_{k.name}": kitti_frames(k, args.kitti_scans) for k in args.kitti}
        sets.update({f"sim_{s}": sim_frames(s, args.seed, args.pairs + 1) for s in args.scenes})
        figures["timing"] = timing(runner, sets, args)
    if args.skip != "wrong":
        figures["wrong_start"] = wrong_starts(runner, args)
    runner.reg.close()
    _common.write_json(args.out, "good_start.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
