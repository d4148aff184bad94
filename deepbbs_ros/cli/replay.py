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

import sys
from pathlib import Path

from deepbbs_ros.cli.common import cli_entry
from deepbbs_ros.cli.replay_hints import FEW_PAIRS, PositionLog, count_pairs, ground_truth_hint, pair_count_hint
from deepbbs_ros.cli.replay_parser import MODES, PROG, _config, build_parser, fleet_overrides
from deepbbs_ros.cli.replay_run import run_replay

__all__ = [  # the parser, the run and the hints live in replay_parser, replay_run and replay_hints
    "FEW_PAIRS", "MODES", "PROG", "PositionLog", "build_parser", "build_tracker", "check_counts",
    "check_localization_args", "count_pairs", "fleet_overrides", "ground_truth_hint", "main", "pair_count_hint",
    "replay_recording", "run_fleet", "run_replay",
]


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
    from deepbbs_ros.errors import DatasetError

    cfg = _config(args)
    check_localization_args(args)
    from deepbbs_ros.replay.methods import parse_methods

    names = parse_methods(args.method, "odometry" if args.mode == "localization" else args.mode)
    check_counts(args)
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


def check_counts(args) -> None:
    """--max-frames and --max-pairs, when given, are >= 1."""
    from deepbbs_ros.errors import ConfigError

    for flag in ("max_frames", "max_pairs"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise ConfigError(f"--{flag.replace('_', '-')} must be >= 1")


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

    from deepbbs_ros.core.localization import MapLocalizer
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.core.tracking import MapTracker
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
    check_counts(args)
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
