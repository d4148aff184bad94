"""deepbbs-replay: evaluate DeepBBS++ and baselines on a recording (pairs protocol or odometry).

Examples::

    deepbbs-replay bags/sample_drive --mode pairs --method deepbbs++,gicp --stride 10
    deepbbs-replay drive.mcap --mode odometry --method deepbbs++,kiss-icp,gicp --out results/replay
    deepbbs-replay apollo/session --perturb-yaw 45 --trials 3 --seed 1
    deepbbs-replay drive.mcap --mode odometry --method deepbbs++,kiss-icp --drop-frames 5 --seed 3

Writes ``OUT/<timestamp>/`` (``OUT/latest`` points at it): metrics.json, pairs.csv or frames.csv,
traj/*.tum|*.kitti, *.png, config_used.yaml, results_bag/ (rosbag2, mcap). Exit codes: 0 done,
1 error (or a recording fault mid-way: results so far are written, marked incomplete), 130 Ctrl-C
(results so far are written, marked incomplete).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from deepbbs_ros.cli.common import cli_entry

PROG = "deepbbs-replay"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG,
        description="Replay a recording through DeepBBS++ and baselines; write metrics, plots, trajectories "
        "and a results bag.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("source", metavar="SOURCE",
                   help="ROS 1 .bag, rosbag2 directory, .mcap/.db3, Apollo folder (pcds/) or KITTI folder (velodyne/)")
    g = p.add_argument_group("what to run")
    g.add_argument("--mode", choices=("pairs", "odometry"), default="pairs",
                   help="pairs: Apollo pair protocol; odometry: a trajectory per method")
    g.add_argument("--method", default="deepbbs++",
                   help="comma list of deepbbs++ (odometry: the local-map pipeline), deepbbs++s2s (odometry only: "
                   "chained scan-to-scan), deepbbs++gicp, deepbbs (deep passes only), icp, plane-icp, gicp, "
                   "kiss-icp (odometry only), kiss-matcher, kiss-matcher+gicp (global, pairs only)")
    g.add_argument("--stride", type=int, default=None,
                   help="pairs: a source frame every N frames (eval.stride); odometry: every N-th frame "
                   "(eval.odom_stride)")
    g.add_argument("--max-dist", type=float, default=None, metavar="M", help="pairs: max source-target distance, m")
    g.add_argument("--perturb-yaw", type=float, default=None, metavar="DEG",
                   help="pairs: random initial yaw in [-DEG, DEG] (basin of convergence)")
    g.add_argument("--perturb-trans", type=float, default=None, metavar="M",
                   help="pairs: random horizontal initial offset up to M metres")
    g.add_argument("--trials", type=int, default=None, help="pairs: perturbed trials per pair")
    g.add_argument("--seed", type=int, default=None, help="seed of the perturbations, dropped frames, wrong priors")
    g.add_argument("--drop-frames", type=int, default=None, metavar="N",
                   help="odometry: skip N runs of 3-10 consecutive scans at random points (eval.drop_frames)")
    g.add_argument("--wrong-prior", type=int, default=None, metavar="N",
                   help="odometry: at N random frames the motion prior is off by up to 30 deg / 2 m (eval.wrong_prior)")
    g.add_argument("--max-frames", type=int, default=None, help="stop after this many frames (odometry: kept frames)")
    g.add_argument("--max-pairs", type=int, default=None, help="pairs: stop after this many pairs")
    i = p.add_argument_group("input")
    i.add_argument("--topic", default=None, help="PointCloud2 topic (bags; default: the only one)")
    i.add_argument("--gt-topic", default=None, help="ground-truth pose topic (bags; default: /ground_truth/pose)")
    i.add_argument("--gt-tolerance", type=float, default=0.05, metavar="S", help="max scan/pose stamp gap, s")
    m = p.add_argument_group("model and config")
    m.add_argument("--config", default=None, metavar="YAML", help="config file (plain sections or ROS params)")
    m.add_argument("--weights", default=None, metavar="PATH", help="DeepBBS++ checkpoint (default: the shipped one)")
    m.add_argument("--device", default=None, help="auto, cpu, cuda, cuda:N (default: registration.device)")
    o = p.add_argument_group("output")
    o.add_argument("--out", default="results/replay", metavar="DIR", help="writes DIR/<timestamp>/ and DIR/latest")
    o.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    o.add_argument("--no-bag", action="store_true", help="skip the results bag")
    o.add_argument("--quiet", action="store_true", help="no progress bar")
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
    return load_config(args.config, overrides)


@cli_entry(PROG)
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from deepbbs_ros.errors import ConfigError, DatasetError

    cfg = _config(args)
    from deepbbs_ros.replay.methods import parse_methods

    names = parse_methods(args.method, args.mode)
    for flag in ("max_frames", "max_pairs"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise ConfigError(f"--{flag.replace('_', '-')} must be >= 1")

    from deepbbs_ros.datasets import open_source

    source = open_source(args.source, topic=args.topic, gt_topic=args.gt_topic, gt_tolerance_s=args.gt_tolerance,
                         lenient=True)
    if args.mode == "pairs" and not source.has_ground_truth:
        raise DatasetError(f"{args.source}: pairs mode needs ground-truth poses (none found); "
                           "use --mode odometry or give --gt-topic")

    from deepbbs_ros.replay.methods import build_methods

    methods = build_methods(names, cfg, weights=args.weights, device=args.device, mode=args.mode)
    return run_replay(args, cfg, source, methods)


def run_replay(args, cfg, source, methods) -> int:
    """Run the loop with a progress bar, then write every output (also after Ctrl-C / a reader fault)."""
    from tqdm import tqdm

    from deepbbs_ros.errors import DatasetError
    from deepbbs_ros.replay import report
    from deepbbs_ros.replay.runner import OdometryResults, PairResults, run_odometry, run_pairs

    run = report.make_run_dir(args.out)
    cfg.to_yaml(run / "config_used.yaml")
    total = len(source)
    if args.max_frames and args.mode == "odometry":
        total = min(total, args.max_frames * cfg.eval.odom_stride)
    bar = tqdm(total=total, unit="frames", desc=f"replay {args.mode}", disable=args.quiet, dynamic_ncols=True)
    interrupted = False
    if args.mode == "pairs":
        res = PairResults(list(methods))

        def progress(n):
            bar.update(n)
            bar.set_postfix(pairs=res.pairs, refresh=False)

        try:
            run_pairs(source, methods, cfg, max_pairs=args.max_pairs, progress=progress, results=res)
        except KeyboardInterrupt:  # outside the loop proper (e.g. while closing the reader)
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
        res.errors.extend(f"recording fault after {res.frames_read} frames: {e}" for e in source.errors)

    if res.frames_read == 0 and source.errors:
        raise DatasetError(f"no scan could be read: {source.errors[0]}")

    if args.mode == "pairs":
        mm = report.pair_metrics(res, cfg)
    else:
        mm = report.odometry_metrics(res)
    extra = {"weights": str(args.weights or cfg.registration.weights or "shipped default"),
             "device": args.device or cfg.registration.device}
    report.write_metrics_json(run / "metrics.json", source=str(args.source), mode=args.mode, res=res, config=cfg,
                              method_metrics=mm, extra=extra)
    if args.mode == "pairs":
        report.write_pairs_csv(run / "pairs.csv", res)
    else:
        report.write_odometry_csv(run / "frames.csv", res)
        report.write_trajectories(run, res)
    plots = []
    if not args.no_plots:
        from deepbbs_ros.replay import plots as P

        if args.mode == "pairs":
            plots = P.plot_pairs(run, res, cfg.eval.success_rot_deg, cfg.eval.success_trans)
        else:
            plots = P.plot_odometry(run, res)
    if not args.no_bag:
        report.write_results_bag(run / "results_bag", res)

    title = f"deepbbs-replay {args.mode}: {Path(args.source).name}" + ("" if res.complete else " (INCOMPLETE)")
    report.print_table(args.mode, mm, title=title)
    print(f"results: {run}  (latest: {Path(args.out) / 'latest'})")
    if plots:
        print("plots:   " + ", ".join(p.name for p in plots))
    if interrupted:
        print(f"{PROG}: interrupted; results so far written to {run} (marked incomplete)", file=sys.stderr)
        return 130
    if not res.complete:
        print(f"{PROG}: error: {res.errors[-1]} (results so far written to {run}, marked incomplete)",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
