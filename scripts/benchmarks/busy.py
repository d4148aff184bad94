#!/usr/bin/env python3
"""Raw KITTI pairs on a busy computer: DeepBBS++ (the shipped pipeline) and small_gicp GICP, with and without a
CPU-bound background process, under OpenMP's passive and spinning wait policies.

Figures (``busy.json``, ``busy.png`` under ``--out``): per wait policy and load, p50 / p95 ms per raw pair of
DeepBBS++ and of GICP and the ratio of the p50s. Each (policy, load) cell runs in a fresh process (OpenMP reads
OMP_WAIT_POLICY when it loads): the scans of every ``--kitti`` sequence paired up to 5 m apart, registered
raw-to-raw from identity ``--rounds`` times; the background load is one process of single-threaded float32
matrix products (a training job's kind of work). deepbbs_ros sets OMP_WAIT_POLICY=PASSIVE unless the user set
it; "default" is libgomp's own behaviour (spin a while, then sleep), "spin:N" the same with GOMP_SPINCOUNT=N.

    python scripts/benchmarks/busy.py --kitti PATH/TO/kitti/00 PATH/TO/kitti/02 --rounds 1 --policies passive,default
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)

WORKER = r"""
import json, sys, time
import numpy as np
from pathlib import Path
from deepbbs_ros.baselines import SmallGicpRegistration
from deepbbs_ros.config import Config
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.datasets import open_source
from itertools import islice
seqs, rounds, limit = json.loads(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
pairs = []
for seq in seqs:
    scans = list(islice(open_source(seq), limit))
    for i, s in enumerate(scans):
        for t in scans[i + 1:]:
            if np.linalg.norm(t.T_world_lidar[:3, 3] - s.T_world_lidar[:3, 3]) <= 5.0:
                pairs.append((s.points.astype(np.float32), t.points.astype(np.float32)))
cfg = Config()
reg = DeepBBSRegistration(cfg)
reg.warmup()
gicp = SmallGicpRegistration("gicp", cfg, threads=cfg.registration.polish_threads)  # DeepBBS++'s GICP threads
out = {"deepbbs++": [], "gicp": []}
for _ in range(rounds):
    for src, tgt in pairs:
        t0 = time.perf_counter(); reg.register(src, tgt); out["deepbbs++"].append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter(); gicp.align(gicp.preprocess(src), gicp.preprocess(tgt), None)
        out["gicp"].append((time.perf_counter() - t0) * 1e3)
print(json.dumps(out))
"""

BURNER = r"""
import numpy as np, time
a = np.random.rand(512, 512).astype(np.float32)
while True:
    a = (a @ a) / 512.0 + 0.01
"""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--kitti", nargs="+", required=True, help="KITTI odometry sequence folders, e.g. PATH/TO/kitti/00")
    p.add_argument("--out", default="results/benchmarks", help="folder for busy.json and busy.png")
    p.add_argument("--scans", type=int, default=10, help="the first scans of each KITTI sequence")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--policies", default="passive,active",
                   help="comma list: passive, active, default (OpenMP's own: spin a while, then sleep), "
                        "spin:N (default policy with GOMP_SPINCOUNT=N)")
    args = p.parse_args(argv)
    import numpy as np

    rows = []
    for policy in args.policies.split(","):
        env_policy = {"passive": {"OMP_WAIT_POLICY": "PASSIVE"}, "active": {"OMP_WAIT_POLICY": "ACTIVE"},
                      "default": {"OMP_WAIT_POLICY": ""}}.get(policy)  # "" keeps deepbbs_ros from setting one
        if env_policy is None and policy.startswith("spin:"):
            env_policy = {"OMP_WAIT_POLICY": "", "GOMP_SPINCOUNT": policy.split(":", 1)[1]}
        if env_policy is None:
            p.error(f"unknown policy {policy!r}")
        for busy in (False, True):
            burner = None
            if busy:
                burner = subprocess.Popen([sys.executable, "-c", BURNER],
                                          env={**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
                time.sleep(1.0)
            try:
                env = {**os.environ, **env_policy,
                       "PYTHONPATH": os.pathsep.join([str(_common.ROOT), os.environ.get("PYTHONPATH", "")])}
                res = subprocess.run([sys.executable, "-c", WORKER, json.dumps(args.kitti), str(args.rounds),
                                      str(args.scans)],
                                     env=env,
                                     capture_output=True, text=True, check=True)
            finally:
                if burner is not None:
                    burner.kill()
                    burner.wait()
            ms = json.loads(res.stdout.strip().splitlines()[-1])
            d, g = np.asarray(ms["deepbbs++"]), np.asarray(ms["gicp"])
            rows.append((policy, "busy" if busy else "idle", len(d), *np.percentile(d, [50, 95]),
                         *np.percentile(g, [50, 95])))
            r = rows[-1]
            print(f"  {r[0]:>7} {r[1]}: deepbbs++ p50 {r[3]:.0f} ms, gicp p50 {r[5]:.0f} ms", file=sys.stderr)
    print(f"\n{'OMP_WAIT_POLICY':<16} {'load':<5} {'pairs':>5} {'DeepBBS++ p50':>14} {'p95':>7} "
          f"{'GICP p50':>9} {'p95':>7} {'p50 ratio':>10}")
    for pol, load, n, dp50, dp95, gp50, gp95 in rows:
        print(f"{pol:<16} {load:<5} {n:>5} {dp50:>11.1f} ms {dp95:>7.1f} {gp50:>6.1f} ms {gp95:>7.1f} "
              f"{dp50 / gp50:>10.2f}")
    out = Path(args.out)
    keys = ("policy", "load", "pairs", "deepbbs_p50_ms", "deepbbs_p95_ms", "gicp_p50_ms", "gicp_p95_ms")
    cells = [dict(zip(keys, r), p50_over_gicp=r[3] / r[5]) for r in rows]
    _common.write_json(out, "busy.json", {"rounds": args.rounds, "cells": cells})
    plt = _common.pyplot()
    fig, ax = plt.subplots(figsize=(8, 3.5))
    labels = [f"{c['policy']}\n{c['load']}" for c in cells]
    x = np.arange(len(cells))
    ax.bar(x - 0.2, [c["deepbbs_p50_ms"] for c in cells], 0.4, label="DeepBBS++ p50")
    ax.bar(x + 0.2, [c["gicp_p50_ms"] for c in cells], 0.4, label="GICP p50")
    for i, c in enumerate(cells):
        ax.annotate(f"{c['p50_over_gicp']:.2f}x", (i - 0.2, c["deepbbs_p50_ms"]), ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("ms per raw pair (label: x GICP's p50)")
    ax.legend(fontsize=8)
    _common.save(fig, out, "busy.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
