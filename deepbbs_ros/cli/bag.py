"""``deepbbs-bag``: inspect recordings, convert between formats, build a prior map.

    deepbbs-bag info SRC [--topic T] [--gt-topic G] [--json]
    deepbbs-bag convert SRC DST [--format {mcap,db3,apollo,kitti}] [--topic T] [--gt-topic G] [--lenient]
                        [--out-topic T] [--out-gt-topic G] [--repack]
    deepbbs-bag map SRC OUT.pcd [--voxel M] [--from {truth,odometry}] [--stride N]

SRC is anything :func:`deepbbs_ros.datasets.open_source` reads: a ROS 1 ``.bag``, a rosbag2
directory (sqlite3 or mcap), a bare ``.mcap``/``.db3``, an Apollo session folder, a KITTI folder or
a plain folder of ``.bin``/``.pcd`` scans. ``info`` reads the whole recording (every mcap chunk
checked against its CRC) and reports what it read: every topic with its message count, every
PointCloud2 topic, where metadata.yaml says otherwise and where the recording is damaged. ``map``
accumulates the scans at their ground-truth poses (or the odometry's) into a voxel-downsampled point
cloud (:mod:`deepbbs_ros.core.mapping`) for localization in a prior map.
``convert`` from a ROS 2 bag to a bag copies the clouds as they are (topic, layout, organised
clouds stay organised) unless ``--repack`` or a folder format asks for x y z + fields.
Known errors print one line and exit with status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from deepbbs_ros.cli.common import HelpFormatter, cli_entry

FORMATS = ("mcap", "db3", "bag", "apollo", "kitti")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-bag", description=__doc__.split("\n\n")[0],
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


def _check_map_output(out: str) -> Path:
    """The map file to write, checked before any scan is read: a ``.pcd`` name in a folder that can be written."""
    import os

    from deepbbs_ros.errors import DatasetError

    path = Path(out)
    if path.suffix.lower() != ".pcd":
        raise DatasetError(f"{out}: the map is written as a .pcd file (give a name ending in .pcd)")
    if path.is_dir():
        raise DatasetError(f"{out}: is a directory (give the map file's name, e.g. {path / 'map.pcd'})")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise DatasetError(f"cannot create the folder {path.parent}: {err.strerror or err}") from err
    if not os.access(path.parent, os.W_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise DatasetError(f"{out}: cannot write there (permission denied)")
    return path


def _map(args) -> int:
    from deepbbs_ros.config import load_config
    from deepbbs_ros.core.mapping import build_map
    from deepbbs_ros.datasets.maps import write_map
    from deepbbs_ros.errors import DatasetError
    from deepbbs_ros.replay.runner import offline_threads

    out = _check_map_output(args.out)
    if not args.voxel > 0:
        raise DatasetError(f"--voxel must be > 0 m, got {args.voxel:g}")
    if args.stride < 1 or (args.max_frames is not None and args.max_frames < 1):
        raise DatasetError("--stride and --max-frames must be >= 1")
    from deepbbs_ros.datasets.window import check_window, windowed

    check_window(args.start, args.end)
    cfg = offline_threads(load_config(args.config))  # one thread: the same map on any machine
    args.lenient = True  # a cut recording: the map of what was read, then the fault (exit code 1)
    source = _open(args)
    if len(source) == 0:
        raise DatasetError(f"{args.src}: the recording holds no scan")
    source = windowed(source, args.start, args.end)
    from tqdm import tqdm

    total = len(source)
    bar = tqdm(total=total, unit="frames", desc="map", disable=args.quiet,
               dynamic_ncols=True)
    try:
        built = build_map(source, cfg, voxel=args.voxel, source=args.pose_source or "auto", stride=args.stride,
                          has_ground_truth=source.has_ground_truth, progress=bar.update, max_frames=args.max_frames)
    except DatasetError:
        if hasattr(source, "check_not_empty"):
            source.check_not_empty()  # --start / --end outside the recording: that is the one line
        raise
    finally:
        bar.close()
    if source.errors and built.frames_read == 0:
        raise DatasetError(f"no scan could be read: {source.errors[0]}")
    written = write_map(out, built.points, built.T_map_sensor, built.stamps_ns)
    if not args.no_plot:
        try:
            from deepbbs_ros.replay.plots import plot_map

            written.append(plot_map(out.with_suffix(".png"), built.points, built.T_map_sensor))
        except Exception as err:  # noqa: BLE001 - a plot must not cost the map
            print(f"deepbbs-bag: warning: top view not written ({type(err).__name__}: {err})", file=sys.stderr)
    if built.skipped:
        more = f" (and {len(built.skipped) - 1} more)" if len(built.skipped) > 1 else ""
        print(f"deepbbs-bag: warning: {len(built.skipped)} scans left out of the map: {built.skipped[0]}{more}",
              file=sys.stderr)
    print(f"wrote {', '.join(str(p) for p in written)}: {len(built.points)} points (voxel {built.voxel:g} m) from "
          f"{built.frames_used} of {built.frames_read} scans at their {built.source} poses; map frame: "
          f"{built.map_frame} ({built.timings_ms['total'] / 1e3:.1f} s)")
    if built.interrupted:
        print(f"deepbbs-bag: interrupted; the map of the first {built.frames_read} scans written", file=sys.stderr)
        return 130
    if source.errors:
        print(f"deepbbs-bag: error: {source.errors[0]} (the map of the {built.frames_read} scans before it "
              "written)", file=sys.stderr)
        return 1
    return 0


@cli_entry("deepbbs-bag")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "info":
        return _info(args)
    if args.command == "map":
        return _map(args)
    return _convert(args)


if __name__ == "__main__":
    sys.exit(main())
