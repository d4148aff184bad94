"""What the fixed evaluation thread count costs: per-frame time of the odometry methods with ``eval.threads`` 1 (the
default: the same figures on any machine) against 0 (every core, the live node's setting), on one recording.
Writes ``threads.json`` and ``threads.png`` under ``--out``.

DeepBBS++ and GICP run in this process, both settings frame by frame in alternating order (the same minute, the
same load). KISS-ICP fixes its thread count once per process (TBB), so it runs in child processes, the two
settings alternating. Prints the median ms per frame of each and the ratio 1 thread / every core.

    python scripts/benchmarks/threads.py bags/urban_drive_hdl64 --rounds 3 --out results/benchmarks/latest
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

from deepbbs_ros.config import Config  # noqa: E402
from deepbbs_ros.datasets import open_source  # noqa: E402
from deepbbs_ros.replay.methods import build_methods  # noqa: E402
from deepbbs_ros.replay.runner import offline_threads  # noqa: E402

SETTINGS = {"1 thread": 1, "every core": 0}


def _kiss_child(source: str, threads: int, rounds: int) -> list[float]:
    from deepbbs_ros.baselines import KissICPOdometry

    scans = list(open_source(source))
    cfg = offline_threads(Config().replace(**{"eval.threads": threads}))
    out = []
    for _ in range(rounds):
        odo = KissICPOdometry(cfg)
        for k, s in enumerate(scans):
            t0 = time.perf_counter()
            odo.register(s.points, s.point_times())
            if k:
                out.append((time.perf_counter() - t0) * 1e3)
    return out


def _in_process(source: str, names: list[str], rounds: int) -> dict[tuple[str, str], list[float]]:
    scans = list(open_source(source))
    cfgs = {label: offline_threads(Config().replace(**{"eval.threads": n})) for label, n in SETTINGS.items()}
    times: dict[tuple[str, str], list[float]] = {(c, n): [] for c in cfgs for n in names}
    for r in range(rounds):
        methods = {c: build_methods(names, cfg, mode="odometry") for c, cfg in cfgs.items()}
        prev = {key: None for key in times}
        rel = {key: np.eye(4) for key in times}
        for k, scan in enumerate(scans):
            for c in list(cfgs) if (k + r) % 2 == 0 else list(cfgs)[::-1]:
                for n in names:
                    m, t0 = methods[c][n], time.perf_counter()
                    if hasattr(m, "step"):
                        m.step(scan.points, scan.point_times(), scan.stamp_ns)
                    else:
                        p, _ = m.prepare(scan.points, scan.point_times(), scan.stamp_ns)
                        if prev[c, n] is not None:
                            rel[c, n], _, _ = m.align(p, prev[c, n], rel[c, n])
                        prev[c, n] = p
                    if k:
                        times[c, n].append((time.perf_counter() - t0) * 1e3)
    return times


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("source")
    p.add_argument("--rounds", type=int, default=3, help="passes over the recording per setting")
    p.add_argument("--methods", default="deepbbs++,gicp,kiss-icp")
    p.add_argument("--out", type=Path, default=None, help="folder for threads.json and threads.png")
    p.add_argument("--kiss-child", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.kiss_child is not None:
        print(json.dumps(_kiss_child(args.source, args.kiss_child, 1)))
        return 0
    names = [n for n in args.methods.split(",") if n]
    with open("/proc/loadavg") as fh:
        print(f"load average before: {fh.read().split()[0]}")
    times = _in_process(args.source, [n for n in names if n != "kiss-icp"], args.rounds)
    if "kiss-icp" in names:
        for r in range(args.rounds):
            for label in list(SETTINGS) if r % 2 == 0 else list(SETTINGS)[::-1]:
                cmd = [sys.executable, __file__, args.source, "--kiss-child", str(SETTINGS[label])]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.splitlines()[-1]
                times.setdefault((label, "kiss-icp"), []).extend(json.loads(out))
    with open("/proc/loadavg") as fh:
        print(f"load average after: {fh.read().split()[0]}")
    figures: dict = {"source": args.source, "rounds": args.rounds, "methods": {}}
    for n in names:
        one, every = (statistics.median(times[label, n]) for label in SETTINGS)
        figures["methods"][n] = {"one_thread_ms": one, "every_core_ms": every, "ratio": one / every,
                                 "frames": len(times["1 thread", n])}
        print(f"{n:>10}: 1 thread {one:6.1f} ms/frame, every core {every:6.1f} ms/frame, ratio {one / every:.2f} "
              f"({len(times['1 thread', n])} frames each)")
    if args.out is not None:
        _common.write_json(args.out, "threads.json", figures)
        plt = _common.pyplot()
        fig, ax = plt.subplots(figsize=(6, 3.2))
        x = np.arange(len(names))
        ax.bar(x - 0.2, [figures["methods"][n]["every_core_ms"] for n in names], 0.4, label="every core")
        ax.bar(x + 0.2, [figures["methods"][n]["one_thread_ms"] for n in names], 0.4, label="1 thread (eval.threads)")
        for i, n in enumerate(names):
            ax.annotate(f"x{figures['methods'][n]['ratio']:.2f}", (i + 0.2, figures["methods"][n]["one_thread_ms"]),
                        ha="center", va="bottom", fontsize=8)
        ax.set_xticks(x, names)
        ax.set_ylabel("median ms per frame")
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
        _common.save(fig, args.out, "threads.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
