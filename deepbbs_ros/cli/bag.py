"""``deepbbs-bag``: inspect recordings and convert between formats.

    deepbbs-bag info SRC [--topic T] [--gt-topic G] [--json]
    deepbbs-bag convert SRC DST [--format {mcap,db3,apollo,kitti}] [--topic T] [--gt-topic G] [--lenient]

SRC is anything :func:`deepbbs_ros.datasets.open_source` reads: a ROS 1 ``.bag``, a rosbag2
directory (sqlite3 or mcap), a bare ``.mcap``/``.db3``, an Apollo session folder or a KITTI folder.
Known errors print one line and exit with status 1.
"""

from __future__ import annotations

import argparse
import json
import sys

from deepbbs_ros.cli.common import cli_entry

FORMATS = ("mcap", "db3", "apollo", "kitti")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-bag", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="{info,convert}")

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
        g.add_argument("--lenient", action="store_true", help="keep everything valid before a fault, report it")

    p_info = sub.add_parser("info", help="topics, types, message counts, duration, ground truth")
    add_source_args(p_info)
    p_info.add_argument_group("output").add_argument("--json", action="store_true", help="print JSON")

    p_conv = sub.add_parser("convert", help="convert any readable recording to mcap/db3/apollo/kitti")
    add_source_args(p_conv)
    g = p_conv.add_argument_group("output")
    g.add_argument("dst", metavar="DST", help="output directory (must not exist, or be empty)")
    g.add_argument("--format", choices=FORMATS, default="mcap", help="output format (default: mcap rosbag2)")
    g.add_argument("--out-topic", default=None, help="LiDAR topic in a written bag (default: Apollo's)")
    g.add_argument(
        "--out-gt-topic", default=None, help="ground-truth topic in a written bag (default: /ground_truth/pose)"
    )
    g.add_argument("--max-frames", type=int, default=None, metavar="N", help="convert only the first N frames")
    return parser


def _open(args):
    from deepbbs_ros.datasets import open_source

    return open_source(
        args.src, topic=args.topic, gt_topic=args.gt_topic, gt_tolerance_s=args.gt_tolerance, lenient=args.lenient
    )


def _info(args) -> int:
    source = _open(args)
    info = source.info()
    for err in source.errors:
        print(f"deepbbs-bag: warning: {err}", file=sys.stderr)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
        return 0
    from rich.console import Console
    from rich.table import Table

    console = Console()
    topics = info.get("topics") or [
        {"topic": info["topic"], "type": f"{info['format']} scans", "count": info["frames"]},
        *([{"topic": info["gt_topic"], "type": "poses", "count": info["frames"]}] if info["gt_topic"] else []),
    ]
    table = Table(title=f"{info['path']} ({info['format']})")
    for col, justify in (("topic", "left"), ("type", "left"), ("messages", "right")):
        table.add_column(col, justify=justify)
    for t in topics:
        table.add_row(t["topic"], t["type"], str(t["count"]))
    console.print(table)
    summary = Table(show_header=True)
    for col, justify in (("quantity", "left"), ("value", "right"), ("unit", "left")):
        summary.add_column(col, justify=justify)
    summary.add_row("LiDAR topic", str(info["topic"]), "")
    summary.add_row("frames", str(info["frames"]), "scans")
    if "duration_s" in info:
        summary.add_row("duration", f"{info['duration_s']:.3f}", "s")
    summary.add_row("ground truth", "yes" if info["ground_truth"] else "no", str(info["gt_topic"] or ""))
    console.print(summary)
    return 0


def _convert(args) -> int:
    import itertools

    from deepbbs_ros.datasets import APOLLO_LIDAR_TOPIC, GT_POSE_TOPIC, write_scans
    from deepbbs_ros.datasets.base import SizedIterable

    source = _open(args)
    scans = iter(source)
    total = len(source)
    if args.max_frames is not None:
        scans = itertools.islice(scans, args.max_frames)
        total = min(total, args.max_frames)
    n = write_scans(
        SizedIterable(scans, total),
        args.dst,
        args.format,
        topic=args.out_topic or APOLLO_LIDAR_TOPIC,
        gt_topic=args.out_gt_topic or GT_POSE_TOPIC,
        progress=True,
    )
    for err in source.errors:
        print(f"deepbbs-bag: warning: {err}", file=sys.stderr)
    gt = "with" if source.has_ground_truth else "without"
    print(f"wrote {n} frames {gt} ground truth to {args.dst} ({args.format})")
    return 0


@cli_entry("deepbbs-bag")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "info":
        return _info(args)
    return _convert(args)


if __name__ == "__main__":
    sys.exit(main())
