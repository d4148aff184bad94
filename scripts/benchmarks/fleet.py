#!/usr/bin/env python3
"""Fleet replay: N simulated recordings replayed by ``deepbbs-replay --workers W`` (local Ray), 1 and 2 workers.

Figures (``fleet.json``, ``fleet.png`` under ``--out``): for every method set (``--methods``, ';'-separated) and
worker count (``--workers``), the wall time of the command (Ray's start-up included) and of the fleet (after
Ray is up), the speedup over the first worker count, the mean time of one recording in its worker and the
throughput of the fleet (frames/s) and per CPU (frames/s/CPU), from which a cluster can be sized. Recordings:
``--recordings`` drives of ``--frames`` HDL-64 scans (scenes cycled, seeds from ``--seed``), simulated once into
``--cache``. A task has ``--cpus-per-task`` 1; ``--network-process`` adds the DeepBBS++ sets with 2 CPUs per
recording (its network in a process of its own). Extra arguments after ``--`` go to deepbbs-replay.

    python scripts/benchmarks/fleet.py --out results/benchmarks                  # 8 recordings, 1 vs 2 workers
    python scripts/benchmarks/fleet.py --recordings 16 --workers 1,2,4 --methods "gicp;kiss-icp"
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

SCENES = ("urban", "suburban", "highway", "open_road")


def ensure_recordings(args) -> list[Path]:
    from deepbbs_ros.datasets import open_source, write_scans
    from deepbbs_ros.sim import WORLDS_VERSION, simulate_drive

    root = Path(args.cache).expanduser() if args.cache else (
        Path.home() / ".cache" / "deepbbs_ros" / "bench" / f"fleet_{args.frames}f_w{WORLDS_VERSION}")
    out = []
    for i in range(args.recordings):
        scene, seed = SCENES[i % len(SCENES)], args.seed + i
        path = root / f"{scene}_{seed}"
        try:
            ok = path.exists() and len(open_source(path)) == args.frames
        except Exception:  # noqa: BLE001 - an unreadable cached drive is simulated again
            ok = False
        if not ok:
            import shutil

            shutil.rmtree(path, ignore_errors=True)
            t0 = time.perf_counter()
            write_scans(simulate_drive(scene, seed, args.frames, compensate=True), path, "mcap")
            print(f"simulated {path} ({args.frames} frames, {time.perf_counter() - t0:.0f} s)", flush=True)
        out.append(path)
    return out


def run_once(sources: list[Path], methods: str, workers: int, extra: list[str]) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-fleet-") as tmp:
        cmd = [sys.executable, "-m", "deepbbs_ros.cli.replay", *map(str, sources), "--mode", "odometry",
               "--method", methods, "--workers", str(workers), "--out", tmp, "--quiet", "--no-plots", "--no-bag",
               *extra]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        doc_path = Path(tmp) / "latest" / "metrics.json"
        if not doc_path.exists():
            raise SystemExit(f"fleet: deepbbs-replay failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        doc = json.loads(doc_path.read_text())
    secs = [r["seconds"] for r in doc["recordings"] if r["seconds"]]
    return {"methods": methods, "workers": workers, "rc": proc.returncode, "cmd_wall_s": wall,
            "fleet_wall_s": doc["wall_s"], "frames": doc["frames_read"], "ok": doc["recordings_ok"],
            "total": doc["recordings_total"], "task_s_mean": sum(secs) / max(1, len(secs)),
            "pooled_fps": {m: v.get("fps") for m, v in doc["pooled"].items()}}


def main() -> int:
    argv, extra = _common.split_passthrough(sys.argv[1:])
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--recordings", type=int, default=8, help="simulated recordings")
    p.add_argument("--frames", type=int, default=20, help="HDL-64 frames per recording (10 Hz)")
    p.add_argument("--seed", type=int, default=300, help="seed of the first recording")
    p.add_argument("--workers", default="1,2", help="comma list of worker counts (Ray CPUs)")
    p.add_argument("--methods", default="gicp,kiss-icp;deepbbs++",
                   help="';'-separated method sets, each a deepbbs-replay --method list")
    p.add_argument("--network-process", action="store_true",
                   help="also run every set containing deepbbs++ with 2 CPUs per recording (its network in a "
                   "process of its own)")
    p.add_argument("--cache", help="folder of the simulated recordings")
    p.add_argument("--out", default="results/benchmarks", help="folder for fleet.json and fleet.png")
    args = p.parse_args(argv)
    workers = [int(w) for w in args.workers.split(",") if w.strip()]
    sources = ensure_recordings(args)
    variants: list[tuple[str, str, list[str], int]] = []  # label, methods, extra args, CPUs per recording
    for m in (m.strip() for m in args.methods.split(";") if m.strip()):
        variants.append((m, m, extra, 1))
        if args.network_process and "deepbbs++" in m:
            variants.append((f"{m} (2 CPUs/rec., network apart)", m, [*extra, "--cpus-per-task", "2"], 2))
    rows = []
    for label, methods, ex, cpt in variants:
        base = None
        for w in (w for w in workers if w >= cpt):
            r = run_once(sources, methods, w, ex)
            r["label"] = label
            base = base or r["fleet_wall_s"]
            r["speedup"] = base / r["fleet_wall_s"]
            r["fps"] = r["frames"] / r["fleet_wall_s"]
            r["fps_per_cpu"] = r["fps"] / w
            rows.append(r)
            print(f"  {label}: {w} worker(s) {r['fleet_wall_s']:.1f} s ({r['ok']}/{r['total']} ok)", flush=True)
    print()
    print(f"{args.recordings} recordings x {args.frames} frames (HDL-64, simulated), deepbbs-replay --mode odometry")
    head = (f"{'methods':<38} {'CPUs':>7} {'command s':>10} {'fleet s':>8} {'speedup':>8} "
            f"{'s/recording':>12} {'frames/s':>9} {'frames/s/CPU':>13}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['label']:<38} {r['workers']:>7} {r['cmd_wall_s']:>10.1f} {r['fleet_wall_s']:>8.1f} "
              f"{r['speedup']:>7.2f}x {r['task_s_mean']:>12.2f} {r['fps']:>9.2f} {r['fps_per_cpu']:>13.2f}")
    print("CPUs: --workers (Ray CPUs); command s: the whole deepbbs-replay process (Ray start-up included); "
          "fleet s: after Ray is up; s/recording: one recording in its worker (imports of a fresh worker included)")
    out = Path(args.out)
    _common.write_json(out, "fleet.json", {"recordings": args.recordings, "frames": args.frames, "rows": rows})
    plt = _common.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for label in dict.fromkeys(r["label"] for r in rows):
        rs = [r for r in rows if r["label"] == label]
        axes[0].plot([r["workers"] for r in rs], [r["fleet_wall_s"] for r in rs], "o-", label=label)
        axes[1].plot([r["workers"] for r in rs], [r["fps_per_cpu"] for r in rs], "o-", label=label)
    for ax, lab in ((axes[0], "fleet wall time (s)"), (axes[1], "frames/s per CPU")):
        ax.set_xlabel("workers (Ray CPUs)")
        ax.set_ylabel(lab)
        ax.set_xticks(workers)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"{args.recordings} recordings x {args.frames} frames, odometry")
    _common.save(fig, out, "fleet.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
