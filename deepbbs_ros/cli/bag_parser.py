"""deepbbs-bag's arguments: the parser, a subcommand each (info, convert, map) with argument groups."""

from __future__ import annotations

import argparse

from deepbbs_ros.cli.common import HelpFormatter

#: the first line of ``deepbbs-bag --help`` (the command's docstring, cli/bag.py, says the rest)
DESCRIPTION = "``deepbbs-bag``: inspect recordings, convert between formats, build a prior map."
FORMATS = ("mcap", "db3", "bag", "apollo", "kitti")  # what convert writes


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-bag", description=DESCRIPTION,
                                     formatter_class=HelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="{info,convert,map}")

    def add_source_args(p: argparse.ArgumentParser) -> None:
        g = p.add_argument_group("source")
        g.add_argument("src", metavar="SRC", help="bag file/directory, .mcap, Apollo folder or KITTI folder")
        g.add_argument("--topic", default=None, help="PointCloud2 topic (default: the only one in the bag)")
        g.add_argument(
            "--gt-topic", default=None, help="ground-truth PoseStamped/Odometry/TransformStamped topic "
            "(default: /ground_truth/pose when present)"
        )
        g.add_argument(
            "--gt-tolerance", type=float, default=0.05, metavar="S",
            help="max seconds between a scan stamp and its ground-truth stamp (default: 0.05)",
        )
        if p.prog.endswith(" map"):
            return
        g.add_argument("--lenient", action="store_true",
                       help="convert: keep everything readable (a damaged file or bag chunk costs only itself, a cut "
                       "keeps what is before it), then report the damage (exit code 1)")

    p_info = sub.add_parser("info", help="topics, types, message counts, duration, ground truth",
                            formatter_class=HelpFormatter)
    add_source_args(p_info)
    p_info.add_argument_group("output").add_argument("--json", action="store_true", help="print JSON")

    p_conv = sub.add_parser("convert", help="convert any readable recording to mcap/db3/bag/apollo/kitti",
                            formatter_class=HelpFormatter)
    add_source_args(p_conv)
    g = p_conv.add_argument_group("output")
    g.add_argument("dst", metavar="DST", help="output directory (must not exist, or be empty); a NAME.bag file for "
                   "--format bag")
    g.add_argument("--format", choices=FORMATS, default="mcap",
                   help="output format: mcap / db3 (rosbag2), bag (ROS 1), apollo, kitti folders")
    g.add_argument("--out-topic", default=None,
                   help="LiDAR topic in a written bag (default: the source's; Apollo's for folders)")
    g.add_argument("--out-gt-topic", default=None,
                   help="ground-truth topic in a written bag (default: the source's; /ground_truth/pose for folders)")
    g.add_argument("--repack", action="store_true",
                   help="bag to bag: decode and write x y z + fields, unorganised, ground truth as PoseStamped at "
                   "the scan stamps (default: copy the messages as they are)")
    g.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="convert only the first N frames (default: all)")

    p_map = sub.add_parser(
        "map", help="a prior map (PCD) from a recording's ground truth or odometry, for localization",
        formatter_class=HelpFormatter,
        description="Accumulate every scan at its pose into a voxel-downsampled point cloud in the map frame "
        "(the ground truth's world frame; the first scan's frame when there is none) and write OUT.pcd, the "
        "trajectory beside it (OUT.tum, TUM format: what localization takes as the map's places) and a top view "
        "(OUT.png). A recording cut short gives the map of what was read, and exit code 1.")
    add_source_args(p_map)
    g = p_map.add_argument_group("map")
    g.add_argument("out", metavar="OUT.pcd", help="the map file to write (binary PCD); OUT.tum and OUT.png beside it")
    g.add_argument("--voxel", type=float, default=0.2, metavar="M", help="voxel size of the map, m")
    g.add_argument("--from", dest="pose_source", choices=("truth", "odometry"), default=None,
                   help="the scans' poses: the recording's ground truth, or the DeepBBS++ odometry (as "
                   "deepbbs-replay --mode odometry) (default: truth when the recording has it, else odometry)")
    g.add_argument("--stride", type=int, default=1, metavar="N", help="use every N-th scan")
    g.add_argument("--max-frames", type=int, default=None, metavar="N",
                   help="use only the first N scans (after --stride) (default: all)")
    g.add_argument("--start", type=float, default=None, metavar="S",
                   help="use the scans from S seconds after the recording's first scan (default: the first)")
    g.add_argument("--end", type=float, default=None, metavar="S",
                   help="use the scans before S seconds after the recording's first scan; the rest of the drive can "
                   "then be localized in the map ('deepbbs-replay --start S') (default: the last)")
    g.add_argument("--config", default=None, metavar="YAML",
                   help="config file: preprocess.min_range / max_range (the crop) and the odometry's sections "
                   "(default: none, the built-in values)")
    g.add_argument("--no-plot", action="store_true", help="skip the top-view PNG")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser
