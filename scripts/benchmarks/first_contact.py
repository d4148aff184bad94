#!/usr/bin/env python3
"""First contact: a cold node in odometry mode, the sample drive played once at its recorded rate.

Figures (``first_contact.json``, ``first_contact.png`` under ``--out``): per run, the scans the node answered of
those played and its start-up time (``ready in X s``: model loading and warm-up; and from the process start,
imports included). Each run starts ``deepbbs-node`` (odometry mode, a fresh process) and ``deepbbs-play`` at
the same moment (the player waits for the node's subscription, which the node makes once it is ready).
``--loop`` plays the drive twice (the second time after a backward time jump: the odometry restarts).
``--trace`` prints, per run, the node's debug line for each scan (GICP from the prediction, or DeepBBS++ and
why; its timings), each dropped scan, and the node's closing counts. Runs in its own DDS domain on loopback.

    python scripts/benchmarks/first_contact.py --runs 5 --out results/benchmarks
    python scripts/benchmarks/first_contact.py --runs 2 --bag bags/suburban_drive_os64 --loop --trace
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

ROOT = _common.ROOT


def one_run(args: argparse.Namespace, domain: int) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain))
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        node_log = Path(tmp) / "node.log"
        t0, t0_wall = time.monotonic(), time.time()
        with open(node_log, "w") as log:
            debug = ["--log-level", "deepbbs_registration:=debug"] if args.trace else []
            node = subprocess.Popen([py, "-m", "deepbbs_ros.node.registration_node", "--ros-args",
                                     "-p", "node.mode:=odometry", "-r", "cloud:=/points", *debug],
                                    stdout=log, stderr=subprocess.STDOUT, env=env)  # fmt: skip
        n_scans = args.frames * (2 if args.loop else 1)
        echo = subprocess.Popen([py, "-m", "deepbbs_ros.cli.ros", "--timeout", "180", "topic", "echo",
                                 "/deepbbs_registration/pose", "--count", str(n_scans), "--duration", "300"],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)  # fmt: skip
        play = [py, "-m", "deepbbs_ros.cli.play", args.bag, "--cloud-topic", "/points", "--wait", "180", "--quiet"]
        subprocess.run(play, env=env, capture_output=True, timeout=400)
        if args.loop:
            time.sleep(1.0)
            subprocess.run(play, env=env, capture_output=True, timeout=400)
        time.sleep(4.0)
        echo.send_signal(2)
        out, _ = echo.communicate(timeout=30)
        node.send_signal(2)
        node.wait(timeout=30)
        text = node_log.read_text()
    m = re.search(r"ready in ([\d.]+) s \(model ([\d.]+) s, warm-up ([\d.]+) s\)", text)
    stamp = re.search(r"\[(\d+\.\d+)\] \[[^]]*\]: ready in", text)  # the log line's wall-clock time
    return {
        "answered": sum(1 for line in out.splitlines() if line.startswith("PoseStamped")),
        "scans": n_scans,
        "ready_s": float(m.group(1)) if m else float("nan"),
        "model_s": float(m.group(2)) if m else float("nan"),
        "warmup_s": float(m.group(3)) if m else float("nan"),
        "launch_s": float(stamp.group(1)) - t0_wall if stamp else float("nan"),  # process start -> ready
        "wall_s": time.monotonic() - t0,
        "time_jumps": text.count("time jumped back"),
        "trace": [line for line in text.splitlines() if "odometry step" in line or "dropped (scan" in line
                  or "stopping:" in line or "time jumped back" in line or "ERROR" in line or "WARN" in line],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--bag", default=str(ROOT / "bags" / "urban_drive_hdl64"))
    p.add_argument("--frames", type=int, default=15, help="scans in the recording (15 for the samples)")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--loop", action="store_true", help="play the drive twice (a backward time jump between)")
    p.add_argument("--trace", action="store_true", help="print each scan's path (GICP / DeepBBS++ and why), "
                   "its timings, the drops and the node's closing counts")
    p.add_argument("--out", default="results/benchmarks", help="folder for first_contact.json and first_contact.png")
    p.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "77")))
    args = p.parse_args()
    runs = []
    for k in range(args.runs):
        r = one_run(args, args.domain)
        runs.append({key: v for key, v in r.items() if key != "trace"})
        print(f"run {k + 1}: answered {r['answered']} of {r['scans']} scans; ready in {r['ready_s']:.1f} s "
              f"(model {r['model_s']:.1f} s, warm-up {r['warmup_s']:.1f} s; {r['launch_s']:.1f} s from the process "
              f"start, imports included); odometry restarts {r['time_jumps']}",
              flush=True)  # fmt: skip
        if args.trace:
            for line in r["trace"]:
                print("   ", line.split("]: ", 1)[-1], flush=True)
    out = Path(args.out)
    _common.write_json(out, "first_contact.json", {"bag": Path(args.bag).name, "loop": args.loop, "runs": runs})
    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    x = range(1, len(runs) + 1)
    ax.bar([i - 0.2 for i in x], [r["launch_s"] for r in runs], 0.4, label="process start -> ready (s)")
    ax.bar([i + 0.2 for i in x], [r["ready_s"] for r in runs], 0.4, label="ready in (model + warm-up, s)")
    for i, r in zip(x, runs):
        ax.annotate(f"{r['answered']}/{r['scans']} answered", (i, max(r["launch_s"], r["ready_s"]) or 0),
                    ha="center", va="bottom", fontsize=7)
    ax.set_xlabel("run (a fresh node each)")
    ax.set_ylabel("s")
    ax.set_xticks(list(x))
    ax.legend(fontsize=8)
    _common.save(fig, out, "first_contact.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
