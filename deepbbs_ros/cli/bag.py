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

import json
import sys
from pathlib import Path

from deepbbs_ros.cli.bag_parser import FORMATS, build_parser  # noqa: F401  (re-exported)
from deepbbs_ros.cli.common import cli_entry


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
