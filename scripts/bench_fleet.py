#!/usr/bin/env python3
"""Fleet replay benchmark: N simulated recordings replayed by ``deepbbs-replay --workers W`` (local Ray).

1. Simulates ``--recordings`` short drives (``--frames`` HDL-64 scans each, scenes cycled, seeds from
   ``--seed``) into ``--cache`` (default ``~/.cache/deepbbs_ros/bench/fleet_<frames>f_w<worlds version>``)
   unless they are there (rosbag2, mcap);
2. for every method set (``--methods``, ';'-separated) and every worker count (``--workers``, comma list),
   runs ``deepbbs-replay <all recordings> --mode odometry --workers W`` in a fresh process;
3. prints one table: wall time of the command (Ray start-up included) and of the fleet (after Ray is up),
   the speedup over the first worker count, the mean time of one recording in its worker, and the
   throughput of the fleet (frames/s) and per CPU (frames/s/CPU), from which a cluster can be sized.

Example::

    python scripts/bench_fleet.py                                    # 8 recordings, 1 vs 2 workers
    python scripts/bench_fleet.py --recordings 16 --workers 1,2,4 --methods "gicp;kiss-icp"
    python scripts/bench_fleet.py --methods "deepbbs++" --network-process  # + 2 CPUs/recording, network apart

A fleet task has ``--cpus-per-task`` CPUs (1): DeepBBS++ runs its network in its own process (what a
single run does on a CPU, ``registration.network_process: auto``) only with 2 or more; ``--network-process``
adds that variant (``--cpus-per-task 2``). Extra arguments after ``--`` go to deepbbs-replay.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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
            raise SystemExit(f"bench_fleet: deepbbs-replay failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
        doc = json.loads(doc_path.read_text())
    secs = [r["seconds"] for r in doc["recordings"] if r["seconds"]]
    return {"methods": methods, "workers": workers, "rc": proc.returncode, "cmd_wall_s": wall,
            "fleet_wall_s": doc["wall_s"], "frames": doc["frames_read"], "ok": doc["recordings_ok"],
            "total": doc["recordings_total"], "task_s_mean": sum(secs) / max(1, len(secs)),
            "pooled_fps": {m: v.get("fps") for m, v in doc["pooled"].items()}}


def main() -> int:
    argv = sys.argv[1:]
    extra = []
    if "--" in argv:
        k = argv.index("--")
        argv, extra = argv[:k], argv[k + 1:]
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
    p.add_argument("--json", help="also write the rows to this JSON file")
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
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
