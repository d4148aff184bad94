"""``deepbbs-bag``: inspect recordings and convert between formats.

    deepbbs-bag info SRC [--topic T] [--gt-topic G] [--json]
    deepbbs-bag convert SRC DST [--format {mcap,db3,apollo,kitti}] [--topic T] [--gt-topic G] [--lenient]
                        [--out-topic T] [--out-gt-topic G] [--repack]

SRC is anything :func:`deepbbs_ros.datasets.open_source` reads: a ROS 1 ``.bag``, a rosbag2
directory (sqlite3 or mcap), a bare ``.mcap``/``.db3``, an Apollo session folder, a KITTI folder or
a plain folder of ``.bin``/``.pcd`` scans. ``info`` reads the whole recording (every mcap chunk
checked against its CRC) and reports what it read: every topic with its message count, every
PointCloud2 topic, where metadata.yaml says otherwise and where the recording is damaged.
``convert`` from a ROS 2 bag to a bag copies the clouds as they are (topic, layout, organised
clouds stay organised) unless ``--repack`` or a folder format asks for x y z + fields.
Known errors print one line and exit with status 1.
"""

from __future__ import annotations

import argparse
import json
import sys

from deepbbs_ros.cli.common import HelpFormatter, cli_entry

FORMATS = ("mcap", "db3", "bag", "apollo", "kitti")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-bag", description=__doc__.split("\n\n")[0],
                                     formatter_class=HelpFormatter)
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
    return parser


def _open(args, **kw):
    from deepbbs_ros.datasets import open_source

    return open_source(
        args.src, topic=args.topic, gt_topic=args.gt_topic, gt_tolerance_s=args.gt_tolerance, lenient=args.lenient,
        **kw,
    )


def _info(args) -> int:
    source = _open(args, any_topic=True)
    info = source.info()
    notes = list(getattr(source, "warnings", []))
    if info.get("metadata_counts"):
        read = {t["topic"]: t["count"] for t in info.get("topics", [])}
        notes.append("metadata.yaml disagrees with what was read: " + ", ".join(
            f"{t} {n} (read {read.get(t, 0)})" for t, n in sorted(info["metadata_counts"].items())))
    if info.get("damage"):
        notes.append(f"damaged recording, counts are up to the damage: {info['damage']}")
    for note in notes + [e for e in source.errors if e != info.get("damage")]:
        print(f"deepbbs-bag: warning: {note}", file=sys.stderr)
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
    clouds = info.get("cloud_topics")
    if info["topic"] is None and clouds:
        summary.add_row("LiDAR topics", ", ".join(clouds), "replay/convert: pick one with --topic")
    else:
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
    from deepbbs_ros.datasets.rosbag import BagSource

    source = _open(args)
    is_bag = isinstance(source, BagSource)
    if is_bag and args.format in ("mcap", "db3") and not args.repack and source.format != "rosbag1":
        n = source.copy_to(args.dst, "mcap" if args.format == "mcap" else "sqlite3", topic=args.out_topic,
                           gt_topic=args.out_gt_topic, max_frames=args.max_frames)
        how = f"{args.out_topic or source.topic}, copied as recorded"
    else:
        scans = iter(source)
        total = len(source)
        if args.max_frames is not None:
            scans = itertools.islice(scans, args.max_frames)
            total = min(total, args.max_frames)
        topic = args.out_topic or (source.topic if is_bag else APOLLO_LIDAR_TOPIC)
        n = write_scans(
            SizedIterable(scans, total),
            args.dst,
            args.format,
            topic=topic,
            gt_topic=args.out_gt_topic or (source.gt_topic if is_bag and source.gt_topic else GT_POSE_TOPIC),
            progress=True,
        )
        how = topic if args.format in ("mcap", "db3") else "x y z intensity"
    gt = "with" if source.has_ground_truth else "without"
    if source.errors:
        print(f"deepbbs-bag: error: {source.errors[0]} ({n} frames before it written to {args.dst})", file=sys.stderr)
        return 1
    print(f"wrote {n} frames {gt} ground truth to {args.dst} ({args.format}: {how})")
    return 0


@cli_entry("deepbbs-bag")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "info":
        return _info(args)
    return _convert(args)


if __name__ == "__main__":
    sys.exit(main())
