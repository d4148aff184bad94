"""deepbbs-replay's arguments: the parser (argument groups) and the config they give (``eval.*`` overrides, a
fleet task's share of the machine)."""

from __future__ import annotations

import argparse

from deepbbs_ros.cli.common import HelpFormatter, config_default

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
                   "chained scan-to-scan), deepbbs++gicp, deepbbs (the network alone: deep passes from the one "
                   "start, no search, no GICP), icp, plane-icp, gicp, kiss-icp (odometry only), kiss-matcher, "
                   "kiss-matcher+gicp (global, pairs only)")
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
