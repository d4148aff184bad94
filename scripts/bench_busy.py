#!/usr/bin/env python3
"""Raw KITTI pairs on a busy computer: DeepBBS++ (default pipeline) and small_gicp GICP, with and without a
CPU-bound background process, under OpenMP's spinning and passive wait policies (issue 10).

    python scripts/bench_busy.py [--realdata ../shared/realdata] [--rounds 3] [--policies passive,active,default]

Each (policy, load) cell runs in a fresh process (OMP_WAIT_POLICY is read when OpenMP loads): the real
KITTI scans in ``--realdata``/kitti/* paired up to 5 m apart, registered raw-to-raw from identity
``--rounds`` times; the background load is one process doing single-threaded float32 matrix products
(a training job's kind of work). Prints p50 / p95 per pair and the ratio to GICP in the same cell.
deepbbs_ros sets OMP_WAIT_POLICY=PASSIVE unless the user set it; "default" is libgomp's own behaviour
(spin a while, then sleep), "spin:N" the same with GOMP_SPINCOUNT=N.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

WORKER = r"""
import json, sys, time
import numpy as np
from pathlib import Path
from deepbbs_ros.baselines import SmallGicpRegistration
from deepbbs_ros.config import Config
from deepbbs_ros.core.registration import DeepBBSRegistration
from deepbbs_ros.datasets import open_source
real, rounds = Path(sys.argv[1]), int(sys.argv[2])
pairs = []
for seq in sorted((real / "kitti").glob("*")):
    scans = list(open_source(seq))
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
    p.add_argument("--realdata", default="../shared/realdata")
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
                env = {**os.environ, **env_policy}
                res = subprocess.run([sys.executable, "-c", WORKER, args.realdata, str(args.rounds)], env=env,
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
