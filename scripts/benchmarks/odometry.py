#!/usr/bin/env python3
"""Odometry: the DeepBBS++ odometry against KISS-ICP and chained scan-to-scan GICP, on a simulated drive and on
real KITTI sequences.

Figures (``odometry.json``, ``odometry.png`` under ``--out``; each run's own ``metrics.json``, trajectories and
plots under ``--out``/odometry/<run>/latest): KITTI drift (segments of 100 m and longer), ATE RMSE, RPE and
throughput (frames/s, with its ratio to KISS-ICP's in the same run) of every method on a held-out simulated
HDL-64E drive of ``--frames`` raw sweeps (simulated once into ``--cache``), the same drive with ``--variants``
(``drop``: 8 gaps of 3-10 dropped scans; ``wrong-prior``: 10 motion priors off by up to 30 deg / 2 m; KISS-ICP
is left out of these, a diverged KISS-ICP takes seconds a scan), every ``--kitti`` sequence as it is, every ``--real``
recording (any folder or bag deepbbs-replay reads) and, per sensor family, simulated ``--rigs`` (place:sensor:mount,
``--rig-frames`` each, simulated once into ``--cache``): ATE, RPE and the largest single-step error side by side.

    python scripts/benchmarks/odometry.py --frames 1000 --kitti PATH/TO/kitti/00 PATH/TO/kitti/02
    python scripts/benchmarks/odometry.py --frames 0 --real PATH/TO/livox_avia_loop PATH/TO/nuscenes_hdl32 \
        --rigs corridor:vlp16:wheeled,garage:avia:handheld,hall:os0_64:legged,courtyard:mid360:handheld
    python scripts/benchmarks/odometry.py --frames 300 --variants clean -- --device cuda   # after --: deepbbs-replay
    python scripts/benchmarks/odometry.py --timing --seed 7 --rig-frames 40 --rigs highway:vlp16:car   # ms per scan

Extra arguments after ``--`` go to every deepbbs-replay run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402  (puts the checkout first on sys.path)


def _cache_dir(args) -> Path:
    root = Path(args.cache).expanduser() if args.cache else Path.home() / ".cache" / "deepbbs_ros" / "bench"
    az = "" if args.azimuth_step is None else f"_az{args.azimuth_step:g}"
    hz = "" if args.rate_hz == 10.0 else f"_{args.rate_hz:g}hz"
    from deepbbs_ros.sim import WORLDS_VERSION

    return root / f"{args.scene}_{args.seed}_{args.frames}{az}{hz}_w{WORLDS_VERSION}"


def ensure_drive(args) -> Path:
    """Simulate the drive into the cache (mcap rosbag2) unless a complete one is there."""
    from deepbbs_ros.datasets import open_source, write_scans
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    path = _cache_dir(args)
    if path.exists():
        try:
            if len(open_source(path)) == args.frames:
                print(f"using cached drive {path}")
                return path
        except Exception as err:  # noqa: BLE001 - any unreadable cache is regenerated
            print(f"cached drive {path} unreadable ({err}); regenerating")
        import shutil

        shutil.rmtree(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kw = {} if args.azimuth_step is None else {"azimuth_step_deg": args.azimuth_step}
    lidar = LidarConfig.hdl64(**kw)
    print(f"simulating {args.frames} frames ({args.scene}, seed {args.seed}) into {path}")
    tmp = path.with_name(path.name + ".partial")
    if tmp.exists():
        import shutil

        shutil.rmtree(tmp)
    scans = simulate_drive(args.scene, args.seed, args.frames, lidar=lidar, rate_hz=args.rate_hz)
    write_scans(_Sized(scans, args.frames), tmp, "mcap", progress=True)
    tmp.rename(path)
    return path


class _Sized:
    """An iterator with a length, so the writer's progress bar shows an ETA."""

    def __init__(self, it, n):
        self.it, self.n = it, n

    def __iter__(self):
        return iter(self.it)

    def __len__(self):
        return self.n


def ensure_rig(args, rig: str) -> Path:
    """A ``place:sensor:mount`` recording of ``--rig-frames`` raw scans, simulated once into the cache (mcap)."""
    from deepbbs_ros.datasets import open_source, write_scans
    from deepbbs_ros.sim import WORLDS_VERSION
    from deepbbs_ros.sim.rig import make_simulator

    place, sensor, mount = rig.split(":")
    root = Path(args.cache).expanduser() if args.cache else Path.home() / ".cache" / "deepbbs_ros" / "bench"
    path = root / f"rig_{place}_{sensor}_{mount}_{args.seed}_{args.rig_frames}_w{WORLDS_VERSION}"
    if path.exists() and len(open_source(path)) == args.rig_frames:
        return path
    import shutil

    shutil.rmtree(path, ignore_errors=True)
    tmp = path.with_name(path.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    print(f"simulating {rig} ({args.rig_frames} frames, seed {args.seed}) into {path}")
    sim = make_simulator(place, args.seed, sensor, mount, frames=args.rig_frames)
    write_scans(_Sized(iter(sim), args.rig_frames), tmp, "mcap", progress=False)
    tmp.rename(path)
    return path


VARIANTS = {"clean": [], "drop": ["--drop-frames", "8", "--seed", "1"],
            "wrong-prior": ["--wrong-prior", "10", "--seed", "1"]}


def replay_run(source: Path, out: Path, methods: str, extra: list[str]) -> dict | None:
    """One ``deepbbs-replay --mode odometry`` run into ``out``; its metrics.json (None if it wrote none)."""
    from deepbbs_ros.cli.replay import main as replay

    cmd = [str(source), "--mode", "odometry", "--method", methods, "--out", str(out), "--no-bag", *extra]
    print("$ deepbbs-replay " + " ".join(cmd), flush=True)
    replay(cmd)
    path = out / "latest" / "metrics.json"
    return json.loads(path.read_text()) if path.exists() else None


#: --timing: the odometry's variants, timed against KISS-ICP on the same scans
TIMED = {"voxel map alone": {"odometry.line_share": 1.0}, "default": {},
         "map's planes rebuilt every scan": {"odometry.map_covariances": True, "odometry.map_refresh": 0.0}}


def cpu_timing(source: Path, repeats: int = 3) -> dict:
    """Processor ms per scan (one thread, DeepBBS++ off: every variant runs the same stages), the median over the drive
    and the least of ``repeats`` runs, of each ``TIMED`` variant and KISS-ICP (``eval.threads`` 1) on the same scans in
    one process; with each one's ratio to KISS-ICP's."""
    import time

    import numpy as np

    from deepbbs_ros.baselines import KissICPOdometry
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.odometry import DeepBBSOdometry
    from deepbbs_ros.datasets import open_source

    scans = list(open_source(source))
    runs: dict[str, list[float]] = {}
    for _ in range(repeats):
        for name, over in TIMED.items():
            odo = DeepBBSOdometry(Config().replace(**{"odometry.threads": 1, "odometry.deepbbs_init": "never", **over}))
            step = lambda sc, o=odo: o.register_frame(sc.points, sc.point_times(), sc.stamp_ns)  # noqa: E731
            runs.setdefault(name, []).append(_median_ms(scans, step, time.process_time, np))
        kiss = KissICPOdometry(Config().replace(**{"eval.threads": 1}))
        step = lambda sc, k=kiss: k.register(sc.points, sc.point_times())  # noqa: E731
        runs.setdefault("kiss-icp", []).append(_median_ms(scans, step, time.process_time, np))
    best = {k: min(v) for k, v in runs.items()}
    return {k: {"ms": v, "x_kiss_icp": v / best["kiss-icp"]} for k, v in best.items()}


def _median_ms(scans, step, clock, np) -> float:
    ms = []
    for sc in scans:
        t0 = clock()
        step(sc)
        ms.append((clock() - t0) * 1e3)
    return float(np.median(ms[2:]))  # the first motion aside


def summary(doc: dict) -> dict:
    M = doc["methods"]
    kiss = (M.get("kiss-icp") or {}).get("fps")
    out = {}
    for name, m in M.items():
        out[name] = {"frames": m.get("frames"), "kitti_t_err_pct": m.get("kitti_t_err_pct"),
                     "kitti_r_err_deg_per_100m": m.get("kitti_r_err_deg_per_100m"), "ate_rmse_m": m.get("ate_rmse_m"),
                     "rpe_trans_m_mean": (m.get("rpe_trans_m") or {}).get("mean"), "fps": m.get("fps"),
                     "max_step_err_m": (m.get("rpe_trans_m") or {}).get("max"),
                     "fps_over_kiss_icp": m["fps"] / kiss if kiss and m.get("fps") else None,
                     "path_length_m": m.get("path_length_m"), "failed_frames": m.get("failed_frames")}
    return {"complete": doc.get("complete"), "methods": out}


def plot(runs: dict, out: Path) -> None:
    import numpy as np

    plt = _common.pyplot()
    names = list(runs)
    methods = sorted({m for r in runs.values() for m in r["methods"]})
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    w = 0.8 / max(1, len(methods))
    for ax, key, label, log in ((axes[0], "ate_rmse_m", "ATE RMSE (m)", True),
                                (axes[1], "kitti_t_err_pct", "KITTI translation drift (%)", True),
                                (axes[2], "fps", "throughput (frames/s)", False)):
        seen = []
        for k, m in enumerate(methods):
            v = [(runs[r]["methods"].get(m) or {}).get(key) for r in names]
            seen += [x for x in v if x]
            ax.bar(np.arange(len(names)) + k * w, [np.nan if x is None else x for x in v], w, label=m)
        ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2, names, fontsize=8)
        ax.set_ylabel(label)
        if log and seen:
            ax.set_yscale("log")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=8)
    _common.save(fig, out, "odometry.png")


def main(argv: list[str] | None = None) -> int:
    argv, passthrough = _common.split_passthrough(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=1000, help="frames of the simulated drive (0: none)")
    p.add_argument("--scene", default="urban", help="urban, suburban, highway, open_road")
    p.add_argument("--seed", type=int, default=101, help="held-out seed (not used in training)")
    p.add_argument("--azimuth-step", type=float, default=None, help="deg; default: the HDL-64 preset (0.18)")
    p.add_argument("--rate-hz", type=float, default=10.0, help="frame rate; low rates = large inter-frame motion")
    p.add_argument("--method", default="deepbbs++,kiss-icp,gicp")
    p.add_argument("--variants", default="clean,drop,wrong-prior", help=f"comma list of {', '.join(VARIANTS)}")
    p.add_argument("--kitti", nargs="*", default=[], help="KITTI odometry sequence folders, e.g. PATH/TO/kitti/00")
    p.add_argument("--kitti-frames", type=int, default=None, help="the first frames of each KITTI sequence (all)")
    p.add_argument("--real", nargs="*", default=[], help="other real recordings (folders or bags deepbbs-replay reads)")
    p.add_argument("--rigs", default="", help="comma list of simulated place:sensor:mount, e.g. corridor:vlp16:wheeled")
    p.add_argument("--rig-frames", type=int, default=100, help="frames of each --rigs recording")
    p.add_argument("--cache", default=None, help="cache root for simulated drives")
    p.add_argument("--out", default="results/benchmarks", help="folder for odometry.json, odometry.png, odometry/")
    p.add_argument("--config", default=None, help="config YAML passed to deepbbs-replay")
    p.add_argument("--timing", action="store_true",
                   help="instead of the runs: processor ms per scan of the odometry's variants and KISS-ICP on each "
                        "--kitti, --real and --rigs recording (one thread, least of 3 runs)")
    args = p.parse_args(argv)
    if args.timing:
        sources = [Path(x) for x in args.kitti + args.real]
        sources += [ensure_rig(args, r) for r in args.rigs.split(",") if r]
        timing = {}
        for src in sources:
            timing[src.name] = t = cpu_timing(src)
            print(f"{src.name}: " + " | ".join(f"{k} {v['ms']:.1f} ms (x{v['x_kiss_icp']:.2f})" for k, v in t.items()))
        _common.write_json(Path(args.out), "odometry_timing.json", {"timing": timing})
        return 0

    out = Path(args.out)
    extra = (["--config", args.config] if args.config else []) + passthrough
    runs: dict = {}
    if args.frames > 0:
        drive = ensure_drive(args)
        for v in [v for v in args.variants.split(",") if v]:
            methods = args.method if v == "clean" else ",".join(m for m in args.method.split(",") if m != "kiss-icp")
            doc = replay_run(drive, out / "odometry" / f"sim_{args.scene}_{v}", methods, VARIANTS[v] + extra)
            if doc:
                runs[f"sim {args.scene} {args.frames}f {v}"] = summary(doc)
    for seq in args.kitti:
        limit = ["--max-frames", str(args.kitti_frames)] if args.kitti_frames else []
        doc = replay_run(Path(seq), out / "odometry" / f"kitti_{Path(seq).name}", args.method, limit + extra)
        if doc:
            runs[f"KITTI {Path(seq).name}"] = summary(doc)
    for seq in args.real:
        doc = replay_run(Path(seq), out / "odometry" / f"real_{Path(seq).name}", args.method, extra)
        if doc:
            runs[Path(seq).name] = summary(doc)
    for rig in [r for r in args.rigs.split(",") if r]:
        doc = replay_run(ensure_rig(args, rig), out / "odometry" / f"rig_{rig.replace(':', '_')}", args.method, extra)
        if doc:
            runs[f"sim {rig}"] = summary(doc)
    if not runs:
        print("no run wrote metrics", file=sys.stderr)
        return 1
    for name, r in runs.items():
        print(f"\n{name}:")
        for m, v in r["methods"].items():
            f = {k: "-" if x is None else f"{x:.3f}" for k, x in v.items()}
            print(f"  {m:>10}: drift {f['kitti_t_err_pct']} %, ATE {f['ate_rmse_m']} m, RPE {f['rpe_trans_m_mean']} m, "
                  f"max step error {f['max_step_err_m']} m, {f['fps']} frames/s "
                  f"(x{f['fps_over_kiss_icp']} KISS-ICP's)")
    _common.write_json(out, "odometry.json", {"runs": runs})
    plot(runs, out)
    return 0 if all(r["complete"] for r in runs.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
