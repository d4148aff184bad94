"""deepbbs-replay: evaluate DeepBBS++ and baselines on a recording (pairs protocol, odometry, or localization
in a prior map).

Examples::

    deepbbs-replay bags/sample_drive --mode pairs --method deepbbs++,gicp --stride 10
    deepbbs-replay drive.mcap --mode odometry --method deepbbs++,kiss-icp,gicp --out results/replay
    deepbbs-replay apollo/session --perturb-yaw 45 --trials 3 --seed 1
    deepbbs-replay drive.mcap --mode odometry --method deepbbs++,kiss-icp --drop-frames 5 --seed 3
    deepbbs-bag map day1.mcap site.pcd                                          # a prior map (+ site.tum)
    deepbbs-replay day2.mcap --mode localization --map site.pcd                 # day 2 placed in it
    deepbbs-replay 'fleet/*.mcap' --mode odometry --method gicp,kiss-icp --workers 8     # a fleet, local Ray
    deepbbs-replay drives.txt --ray-address head-node:6379                              # a fleet, Ray cluster

Writes ``OUT/<timestamp>/`` (``OUT/latest`` points at it): metrics.json, pairs.csv, frames.csv or scans.csv
(localization), traj/*.tum|*.kitti, *.png, config_used.yaml, results_bag/ (rosbag2, mcap). Exit codes: 0 done,
1 error (or a recording fault mid-way, or not one pair, frame or scan answered: results so far are written,
marked incomplete), 130 Ctrl-C (results so far are written, marked incomplete). ``--start`` / ``--end``: seconds
since the recording's first scan (:mod:`deepbbs_ros.datasets.window`).

Several sources (paths, quoted globs, or a ``.txt`` file with one source per line), ``--workers`` or
``--ray-address`` make a fleet run (:mod:`deepbbs_ros.replay.fleet`): each recording runs as a Ray task
through the same code as a single run and gets its own ``OUT/<timestamp>/<recording>/`` folder; the
top-level metrics.json and recordings.csv hold the per-recording table and the pooled figures.
Exit codes: 0 every recording complete, 1 some failed or are incomplete, 130 Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from deepbbs_ros.cli.common import HelpFormatter, cli_entry, config_default

PROG = "deepbbs-replay"
MODES = ("pairs", "odometry", "localization")


def build_parser() -> argparse.ArgumentParser:
    d = config_default
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Replay a recording through DeepBBS++ and baselines (or localize it in a prior map); write "
        "metrics, plots, trajectories and a results bag. Options that default to a config key (eval.*) take the "
        "value of --config, else the built-in one shown.",
        formatter_class=HelpFormatter,
    )
    p.add_argument("source", metavar="SOURCE", nargs="+",
                   help="ROS 1 .bag, rosbag2 directory, .mcap/.db3, Apollo folder (pcds/), KITTI folder (velodyne/) "
                   "or a folder of .bin/.pcd scans (name order, no ground truth: odometry trajectories and runtime); "
                   "several, a quoted glob or a .txt list (one per line) make a fleet run")
    g = p.add_argument_group("what to run")
    g.add_argument("--mode", choices=MODES, default="pairs",
                   help="pairs: Apollo pair protocol; odometry: a trajectory per method; localization: every scan "
                   "placed in the prior map given with --map, with no initial pose (DeepBBS++ only)")
    g.add_argument("--map", default=None, metavar="MAP",
                   help="localization: the prior map, a .pcd or .ply point cloud in the map frame (the recording's "
                   "ground truth, if any, in the same frame), e.g. from 'deepbbs-bag map'; MAP with the .tum suffix "
                   "beside it, when present, is the drive it was built from (its poses become the candidate places)")
    g.add_argument("--method", default="deepbbs++",
                   help="comma list of deepbbs++ (odometry: the local-map pipeline), deepbbs++s2s (odometry only: "
                   "chained scan-to-scan), deepbbs++gicp, deepbbs (deep passes only), icp, plane-icp, gicp, "
                   "kiss-icp (odometry only), kiss-matcher, kiss-matcher+gicp (global, pairs only)")
    g.add_argument("--stride", type=int, default=None, metavar="N",
                   help="pairs: a source frame every N frames; odometry, localization: every N-th frame (default: "
                   f"{d('eval.stride')} in pairs mode, {d('eval.odom_stride')} in odometry and localization)")
    g.add_argument("--max-dist", type=float, default=None, metavar="M",
                   help=f"pairs: the target is the last frame within M metres of the source (default: "
                   f"{d('eval.max_dist', 'm')})")
    g.add_argument("--perturb-yaw", type=float, default=None, metavar="DEG",
                   help="pairs: random initial yaw in [-DEG, DEG] (basin of convergence) (default: "
                   f"{d('eval.perturb_yaw_deg')}: none)")
    g.add_argument("--perturb-trans", type=float, default=None, metavar="M",
                   help=f"pairs: random horizontal initial offset up to M metres (default: {d('eval.perturb_trans')}: "
                   "none)")
    g.add_argument("--trials", type=int, default=None, metavar="N",
                   help=f"pairs: perturbed trials per pair (default: {d('eval.trials')})")
    g.add_argument("--seed", type=int, default=None,
                   help=f"seed of the perturbations, dropped frames, wrong priors (default: {d('eval.seed')})")
    g.add_argument("--drop-frames", type=int, default=None, metavar="N",
                   help=f"odometry: skip N runs of 3-10 consecutive scans at random points (default: "
                   f"{d('eval.drop_frames')})")
    g.add_argument("--wrong-prior", type=int, default=None, metavar="N",
                   help="odometry: at N random frames the motion prior is off by up to 30 deg / 2 m (default: "
                   f"{d('eval.wrong_prior')})")
    g.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="stop after this many frames (odometry, localization: kept frames) (default: all)")
    g.add_argument("--start", type=float, default=None, metavar="S",
                   help="replay the scans from S seconds after the recording's first scan (default: the first)")
    g.add_argument("--end", type=float, default=None, metavar="S",
                   help="replay the scans before S seconds after the recording's first scan; with --start, a part of "
                   "a drive, e.g. the part 'deepbbs-bag map --end S' left out of the map (default: the last)")
    g.add_argument("--max-pairs", type=int, default=None, metavar="N",
                   help="pairs: stop after this many pairs (default: all)")
    i = p.add_argument_group("input")
    i.add_argument("--topic", default=None, help="PointCloud2 topic (bags; default: the only one)")
    i.add_argument("--gt-topic", default=None,
                   help="ground-truth pose topic (bags; default: /ground_truth/pose, else the only pose topic named "
                   "*ground_truth* or *gt*); folders read their pose file (Apollo: poses/gt_poses.txt, KITTI: "
                   "poses.txt + calib.txt)")
    i.add_argument("--gt-tolerance", type=float, default=0.05, metavar="S", help="max scan/pose stamp gap, s")
    m = p.add_argument_group("model and config")
    m.add_argument("--config", default=None, metavar="YAML",
                   help="config file (plain sections or ROS params) (default: none, the built-in values)")
    m.add_argument("--weights", default=None, metavar="PATH",
                   help="DeepBBS++ checkpoint (default: registration.weights, else the shipped model)")
    m.add_argument("--device", default=None,
                   help=f"auto, cpu, cuda, cuda:N (default: {d('registration.device')})")
    o = p.add_argument_group("output")
    o.add_argument("--out", default="results/replay", metavar="DIR", help="writes DIR/<timestamp>/ and DIR/latest")
    o.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    o.add_argument("--no-bag", action="store_true", help="skip the results bag")
    o.add_argument("--quiet", action="store_true", help="no progress bar")
    f = p.add_argument_group("fleet (several recordings as Ray tasks)")
    f.add_argument("--workers", type=int, default=None, metavar="N",
                   help="start Ray here with N CPUs, N / --cpus-per-task recordings at a time (default: all cores)")
    f.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="join this Ray cluster (HOST:PORT of 'ray start --head', or 'auto') instead (default: none, "
                   "Ray starts here)")
    f.add_argument("--cpus-per-task", type=int, default=1, metavar="N",
                   help="CPUs Ray gives each recording; thread settings of 0 (every core) mean these N, and "
                   "DeepBBS++ runs its network in a process of its own only with N >= 2")
    f.add_argument("--retries", type=int, default=3, help="times Ray reruns a recording whose worker process died")
    f.add_argument("--gpus-per-task", type=float, default=0.0, metavar="G",
                   help="GPUs Ray gives each recording (0: CPU only; e.g. 0.25 shares a GPU between 4 tasks)")
    return p


def _config(args):
    from deepbbs_ros.config import load_config

    overrides = {}
    if args.stride is not None:
        overrides["eval.stride" if args.mode == "pairs" else "eval.odom_stride"] = args.stride
    for flag, key in (("max_dist", "eval.max_dist"), ("perturb_yaw", "eval.perturb_yaw_deg"),
                      ("perturb_trans", "eval.perturb_trans"), ("trials", "eval.trials"), ("seed", "eval.seed"),
                      ("drop_frames", "eval.drop_frames"), ("wrong_prior", "eval.wrong_prior")):
        if getattr(args, flag) is not None:
            overrides[key] = getattr(args, flag)
    overrides.update(getattr(args, "fleet_overrides", None) or {})  # a fleet task's share of the machine
    from deepbbs_ros.replay.runner import offline_threads

    return offline_threads(load_config(args.config, overrides))  # eval.threads: figures independent of the cores


def fleet_overrides(cfg, cpus: int) -> dict:
    """What "every core" means in a fleet task: the task's ``cpus`` (thread settings of 0), and the
    network's own process (``network_process: auto``) only when the task has 2 CPUs or more."""
    out = {key: cpus for key, value in (("eval.threads", cfg.eval.threads), ("odometry.threads", cfg.odometry.threads),
                                         ("registration.polish_threads", cfg.registration.polish_threads))
           if value == 0}
    if cfg.registration.network_process == "auto" and cpus < 2:
        out["registration.network_process"] = "off"
    return out


@cli_entry(PROG)
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from deepbbs_ros.replay.fleet import expand_sources

    sources = expand_sources(args.source)
    if len(sources) > 1 or args.workers is not None or args.ray_address is not None:
        return run_fleet(args, sources)
    args.source = sources[0]
    return replay_recording(args)


def replay_recording(args) -> int:
    """One recording (``args.source``), what ``deepbbs-replay SOURCE`` runs; a fleet runs it per recording."""
    from deepbbs_ros.errors import ConfigError, DatasetError

    cfg = _config(args)
    check_localization_args(args)
    from deepbbs_ros.replay.methods import parse_methods

    names = parse_methods(args.method, "odometry" if args.mode == "localization" else args.mode)
    for flag in ("max_frames", "max_pairs"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise ConfigError(f"--{flag.replace('_', '-')} must be >= 1")
    from deepbbs_ros.datasets.window import check_window, windowed

    check_window(getattr(args, "start", None), getattr(args, "end", None))
    if args.mode == "localization":
        from deepbbs_ros.datasets.maps import read_map

        prior = read_map(args.map)  # a bad map is one line before the recording is opened

    from deepbbs_ros.datasets import open_source

    source = open_source(args.source, topic=args.topic, gt_topic=args.gt_topic, gt_tolerance_s=args.gt_tolerance,
                         lenient=True)
    source = windowed(source, getattr(args, "start", None), getattr(args, "end", None))
    if args.mode == "pairs" and not source.has_ground_truth:
        raise DatasetError(f"{args.source}: pairs mode needs ground-truth poses and found none: "
                           f"{ground_truth_hint(source)}; without them --mode odometry measures trajectories and "
                           "runtime (no errors)")

    if args.mode == "localization":
        tracker, res = build_tracker(prior, cfg, weights=args.weights, device=args.device, quiet=args.quiet)
        return run_replay(args, cfg, source, {"deepbbs++": tracker}, results=res)
    from deepbbs_ros.replay.methods import build_methods

    methods = build_methods(names, cfg, weights=args.weights, device=args.device, mode=args.mode)
    return run_replay(args, cfg, source, methods)


def check_localization_args(args) -> None:
    """--map goes with --mode localization (and the other way round), which runs DeepBBS++ only."""
    from deepbbs_ros.errors import ConfigError

    if args.mode == "localization":
        if not args.map:
            raise ConfigError("--mode localization needs the prior map: --map MAP (.pcd or .ply; 'deepbbs-bag map' "
                              "builds one from a recording)")
        if args.method.replace(" ", "") != "deepbbs++":
            raise ConfigError(f"--mode localization runs DeepBBS++'s map tracker only, not --method {args.method}")
    elif getattr(args, "map", None):
        raise ConfigError(f"--map is the prior map of --mode localization (this run is --mode {args.mode})")


def build_tracker(prior, cfg, *, weights=None, device=None, quiet=False):
    """The map tracker over ``prior`` (a :class:`~deepbbs_ros.datasets.maps.PriorMap`) and the results it fills:
    (MapTracker, LocalizationResults with the map, its places and the set-up time)."""
    import time

    from deepbbs_ros.core.localization import MapLocalizer, MapTracker
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.replay.runner import LocalizationResults

    reg = DeepBBSRegistration(cfg, weights=weights, device=device)
    reg.warmup()  # first-call kernel set-up out of the timed scans
    t0 = time.perf_counter()
    localizer = MapLocalizer(prior.points, cfg, registration=reg, trajectory=prior.trajectory)
    setup_ms = (time.perf_counter() - t0) * 1e3
    places = getattr(localizer, "places", None)
    if not quiet:
        where = (f"{len(prior.trajectory)} trajectory poses" if prior.trajectory is not None
                 else "no trajectory beside it") + (" (not used: it does not fit)" if localizer.trajectory_warning
                                                    else "")
        print(f"map {prior.path}: {len(prior.points)} points, {where}; "
              f"{0 if places is None else len(places)} candidate places ({setup_ms / 1e3:.1f} s)", file=sys.stderr)
    res = LocalizationResults(setup_ms=setup_ms, map_points=len(prior.points), places=places, map_xyz=prior.points)
    if localizer.trajectory_warning:  # among the run's warnings (metrics.json, printed at the end)
        res.warnings.append(f"map {prior.path}: {localizer.trajectory_warning}")
    return MapTracker(localizer, cfg), res


def run_replay(args, cfg, source, methods, results=None) -> int:
    """Run the loop with a progress bar, then write every output (also after Ctrl-C / a reader fault)."""
    from tqdm import tqdm

    from deepbbs_ros.errors import DatasetError
    from deepbbs_ros.replay import report
    from deepbbs_ros.replay.runner import OdometryResults, PairResults, run_localization, run_odometry, run_pairs

    run = report.make_run_dir(args.out)
    cfg.to_yaml(run / "config_used.yaml")
    total = len(source)
    if args.max_frames and args.mode != "pairs":
        total = min(total, args.max_frames * cfg.eval.odom_stride)
    bar = tqdm(total=total, unit="frames", desc=f"replay {args.mode}", disable=args.quiet, dynamic_ncols=True)
    interrupted = False
    if args.mode == "pairs":
        res = PairResults(list(methods))
        logged = PositionLog(source)

        def progress(n):
            bar.update(n)
            bar.set_postfix(pairs=res.pairs, refresh=False)

        try:
            run_pairs(logged, methods, cfg, max_pairs=args.max_pairs, progress=progress, results=res)
        except KeyboardInterrupt:  # outside the loop proper (e.g. while closing the reader)
            res.complete = False
            res.errors.append("interrupted by the user (Ctrl-C)")
    elif args.mode == "localization":
        res = results
        try:
            run_localization(source, methods["deepbbs++"], cfg, max_frames=args.max_frames, progress=bar.update,
                             results=res)
        except KeyboardInterrupt:
            res.complete = False
            res.errors.append("interrupted by the user (Ctrl-C)")
    else:
        res = OdometryResults(list(methods))
        try:
            run_odometry(source, methods, cfg, max_frames=args.max_frames, progress=bar.update, results=res)
        except KeyboardInterrupt:
            res.complete = False
            res.errors.append("interrupted by the user (Ctrl-C)")
    bar.close()
    interrupted = any("Ctrl-C" in e for e in res.errors)
    if source.errors:
        res.complete = False
        at = list(getattr(source, "fault_at", []))
        at += [res.frames_read] * (len(source.errors) - len(at))
        res.errors.extend(f"recording fault after {n} frames: {e}" for n, e in zip(at, source.errors))

    if res.frames_read == 0 and source.errors:
        raise DatasetError(f"no scan could be read: {source.errors[0]}")
    if not interrupted and hasattr(source, "check_not_empty"):
        source.check_not_empty()  # --start / --end outside the recording: one line
    from deepbbs_ros.replay.checks import frame_offset, nothing_answered

    none = None if interrupted else nothing_answered(args.mode, res)
    if none:  # every pair, frame or scan failed: the run says so (results so far written all the same)
        res.complete = False
        res.errors.insert(0, none)

    if args.mode == "pairs":
        mm = report.pair_metrics(res, cfg)
    elif args.mode == "localization":
        mm = report.localization_metrics(res, cfg)
    else:
        mm = report.odometry_metrics(res)
    warnings = list(getattr(source, "warnings", [])) + list(getattr(res, "warnings", []))
    if args.mode == "pairs" and res.complete and not (args.max_pairs and res.pairs >= args.max_pairs):
        hint = pair_count_hint(logged.positions, cfg.eval, res.pairs)
        if hint:
            warnings.append(hint)
    extra = {"weights": str(args.weights or cfg.registration.weights or "shipped default"),
             "device": args.device or cfg.registration.device}
    if args.mode == "localization":
        from deepbbs_ros.datasets.maps import trajectory_path

        tum = trajectory_path(args.map)
        extra["map"] = {"path": str(args.map), "points": res.map_points,
                        "trajectory": str(tum) if tum.is_file() else None}
        offset = frame_offset(res.records, cfg.eval.success_rot_deg, cfg.eval.success_trans)
        if offset:  # every pose off the truth by one rigid motion: the map and the truth in different frames
            extra["frame_offset"] = offset
            warnings.append(offset["message"])

    def write_json():
        report.write_metrics_json(run / "metrics.json", source=str(args.source), mode=args.mode, res=res, config=cfg,
                                  method_metrics=mm, extra={**extra, "warnings": warnings})

    write_json()
    if args.mode == "pairs":
        report.write_pairs_csv(run / "pairs.csv", res)
    elif args.mode == "localization":
        report.write_localization_csv(run / "scans.csv", res)
        report.write_localization_trajectories(run, res)
    else:
        report.write_odometry_csv(run / "frames.csv", res)
        report.write_trajectories(run, res)
    plots = []
    failed_outputs = []
    if not args.no_plots:
        from deepbbs_ros.replay import plots as P

        try:
            if args.mode == "pairs":
                plots = P.plot_pairs(run, res, cfg.eval.success_rot_deg, cfg.eval.success_trans)
            elif args.mode == "localization":
                plots = P.plot_localization(run, res, cfg.eval.success_rot_deg, cfg.eval.success_trans)
            else:
                plots = P.plot_odometry(run, res)
        except Exception as err:  # noqa: BLE001 - a plot must not cost the results already computed
            failed_outputs.append(f"plots not written ({type(err).__name__}: {err})")
    if not args.no_bag:
        try:
            report.write_results_bag(run / "results_bag", res)
        except Exception as err:  # noqa: BLE001 - nor may the results bag
            failed_outputs.append(f"results bag not written ({type(err).__name__}: {err})")
    if failed_outputs:
        warnings.extend(failed_outputs)
        write_json()
    for w in warnings if res.complete else ():  # an incomplete run ends in one error line; all are in metrics.json
        print(f"{PROG}: warning: {w}", file=sys.stderr)

    title = f"deepbbs-replay {args.mode}: {Path(args.source).name}" + ("" if res.complete else " (INCOMPLETE)")
    report.print_table(args.mode, mm, title=title, has_ground_truth=source.has_ground_truth)
    print(f"results: {run}  (latest: {Path(args.out) / 'latest'})")
    if plots:
        print("plots:   " + ", ".join(p.name for p in plots))
    if interrupted:
        print(f"{PROG}: interrupted; results so far written to {run} (marked incomplete)", file=sys.stderr)
        return 130
    if not res.complete:
        more = f"; {len(res.errors) - 1} more in metrics.json" if len(res.errors) > 1 else ""
        print(f"{PROG}: error: {res.errors[0]}{more} (results so far written to {run}, marked incomplete)",
              file=sys.stderr)
        return 1
    return 0


def ground_truth_hint(source) -> str:
    """Where a recording of ``source``'s format keeps its ground truth, for a source without it: the pose
    file of a folder (where and in which format), the topics a bag could take with --gt-topic."""
    path = Path(source.path)
    fmt = getattr(source, "format", "")
    if fmt == "kitti" and getattr(source, "truth_note", ""):
        return source.truth_note
    if fmt == "kitti":
        return (f"add poses.txt to the folder (or ../../poses/{path.name}.txt, KITTI's dataset/poses/): KITTI "
                "odometry format, one line of 12 numbers per scan (the 3x4 row-major pose of camera 0), with "
                "calib.txt holding its 'Tr:' line (LiDAR to camera 0)")
    if fmt == "apollo":
        return ("add poses/gt_poses.txt to the folder: one line per scan, 'index timestamp x y z qx qy qz qw' "
                "(the LiDAR's pose in the world)")
    if fmt == "folder":
        return ("a folder of scans has none: put the scans in a KITTI folder (velodyne/NNNNNN.bin + poses.txt + "
                "calib.txt) or an Apollo folder (pcds/N.pcd + poses/gt_poses.txt)")
    from deepbbs_ros.datasets.rosbag import POSE_TYPES

    topics = getattr(getattr(source, "backend", None), "topics", {}) or {}
    poses = sorted(t for t, (typ, _n) in topics.items() if typ in POSE_TYPES)
    if poses:
        return f"give --gt-topic, one of {', '.join(poses)}"
    kinds = ", ".join(t.rsplit("/", 1)[-1] for t in POSE_TYPES)
    return f"the recording has no pose topic ({kinds}) to give with --gt-topic"


class PositionLog:
    """Iterates a scan source and keeps each scan's ground-truth position ((3,) float64, or None) in stream
    order, for :func:`pair_count_hint`."""

    def __init__(self, source) -> None:
        self.source = source
        self.positions: list = []

    def __iter__(self):
        for scan in self.source:
            T = scan.T_world_lidar
            self.positions.append(None if T is None else [float(v) for v in T[:3, 3]])
            yield scan

    def __len__(self) -> int:
        return len(self.source)


#: fewer pairs than this from a whole recording get a hint (a smaller stride or a larger max distance)
FEW_PAIRS = 10


def count_pairs(positions: list, stride: int, max_dist: float, max_gap: int) -> int:
    """How many pairs :func:`deepbbs_ros.replay.runner.iter_pairs` makes from scans at ``positions`` (stream
    order; None: no ground truth): the protocol itself, run on poses that hold only those positions."""
    from types import SimpleNamespace

    import numpy as np

    from deepbbs_ros.replay.runner import iter_pairs

    def pose(p):
        if p is None:
            return None
        T = np.eye(4)
        T[:3, 3] = p
        return T

    scans = [SimpleNamespace(T_world_lidar=pose(p)) for p in positions]
    return sum(1 for _ in iter_pairs(scans, stride, max_dist, max_gap))


def pair_count_hint(positions: list, ev, pairs: int) -> str | None:
    """A line saying why a recording gave only ``pairs`` pairs and which --stride / --max-dist give more
    (counted on the recording's own ground truth), or None when the count is not small or nothing gives more."""
    import math

    import numpy as np

    n = len(positions)
    if pairs >= FEW_PAIRS or n < 2:
        return None
    why = (f"{pairs} pair{'s' if pairs != 1 else ''} from {n} frames: pairs mode takes a source every "
           f"eval.stride = {ev.stride} frames and as its target the last frame within eval.max_dist = "
           f"{ev.max_dist:g} m")
    candidates = sorted({max(1, n // k) for k in range(1, FEW_PAIRS + 1)} | {1}, reverse=True)

    def best_stride(dist: float) -> tuple[int, int] | None:
        """The largest stride (up to eval.stride) giving FEW_PAIRS pairs, or as many as stride 1 gives."""
        most = count_pairs(positions, 1, dist, ev.max_pair_frames)
        if most <= pairs:
            return None
        for stride in candidates:
            got = count_pairs(positions, stride, dist, ev.max_pair_frames) if stride <= ev.stride else -1
            if got >= min(FEW_PAIRS, most):
                return stride, got
        return None  # pragma: no cover - stride 1 is a candidate

    flags, count = "", pairs
    found = best_stride(ev.max_dist)
    if found:
        flags, count = f"--stride {found[0]}", found[1]
    if count < FEW_PAIRS:  # scans farther apart than max_dist: sources without a target
        P = [np.asarray(p) for p in positions if p is not None]
        steps = [float(np.linalg.norm(b - a)) for a, b in zip(P, P[1:])]
        step = float(np.median(steps)) if steps else 0.0
        if step > ev.max_dist:
            dist = float(math.ceil(1.5 * step))
            found = best_stride(dist)
            if found and found[1] > count:
                stride_flag = f"--stride {found[0]} " if found[0] != ev.stride else ""
                flags, count = f"{stride_flag}--max-dist {dist:g} (the scans are {step:.1f} m apart)", found[1]
    if not flags:
        return None
    return f"{why}; {flags} gives {count} pairs"


def run_fleet(args, sources: list[str]) -> int:
    """Every source as a Ray task through :func:`replay_recording`; the fleet summary at the top."""
    import os

    from deepbbs_ros.errors import ConfigError
    from deepbbs_ros.replay import fleet, report

    if args.workers is not None and args.workers < 1:
        raise ConfigError("--workers must be >= 1")
    if args.retries < 0 or args.gpus_per_task < 0:
        raise ConfigError("--retries and --gpus-per-task must be >= 0")
    if args.cpus_per_task < 1:
        raise ConfigError("--cpus-per-task must be >= 1")
    if args.workers is not None and args.workers < args.cpus_per_task:
        raise ConfigError(f"--workers {args.workers} cannot run a task of --cpus-per-task {args.cpus_per_task}")
    if (args.device or "").startswith("cuda") and args.gpus_per_task <= 0:
        raise ConfigError(f"--device {args.device}: give --gpus-per-task > 0 (Ray gives a task no GPU otherwise)")
    cfg = _config(args)  # a bad config or option is one error here, not one per recording
    args.fleet_overrides = fleet_overrides(cfg, args.cpus_per_task)
    cfg = _config(args)
    from deepbbs_ros.replay.methods import parse_methods

    parse_methods(args.method, args.mode)
    for flag in ("max_frames", "max_pairs"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise ConfigError(f"--{flag.replace('_', '-')} must be >= 1")
    # workers may run elsewhere: absolute paths for every file the single run opens
    sources = [os.path.abspath(s) for s in sources]
    check_localization_args(args)
    for flag in ("config", "weights", "map"):
        if getattr(args, flag) and Path(getattr(args, flag)).exists():
            setattr(args, flag, os.path.abspath(getattr(args, flag)))
    workers = None if args.ray_address else (args.workers or max(
        args.cpus_per_task, min(len(sources) * args.cpus_per_task, os.cpu_count() or 1)))
    run = report.make_run_dir(args.out)
    cfg.to_yaml(run / "config_used.yaml")
    res = fleet.run_fleet(replay_recording, args, sources, run, workers=workers, address=args.ray_address,
                          retries=args.retries, cpus_per_task=args.cpus_per_task, gpus_per_task=args.gpus_per_task,
                          progress=not args.quiet)
    doc = fleet.write_summary(run, res, extra={"method": args.method, "config": args.config})
    fleet.print_summary(doc)
    print(f"results: {run}  (latest: {Path(args.out) / 'latest'})")
    if any("Ctrl-C" in e for e in res.errors):
        print(f"{PROG}: interrupted; finished recordings written to {run} (marked incomplete)", file=sys.stderr)
        return 130
    if not res.complete:
        bad = [r.name for r in res.recordings if r.status != "ok"]
        print(f"{PROG}: error: {len(bad)} of {len(res.recordings)} recordings failed or are incomplete "
              f"({', '.join(bad[:5])}{' ...' if len(bad) > 5 else ''}); see {run / 'metrics.json'}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
