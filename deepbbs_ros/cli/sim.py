"""``deepbbs-sim``: simulate a LiDAR recording (a drive, a robot, a hand) and write it.

    deepbbs-sim --scene urban --seed 0 --frames 100 --format mcap --out drives/urban0
    deepbbs-sim --scene highway --seed 3 --frames 50 --lidar vlp16 --no-motion-distortion --format apollo --out hw3
    deepbbs-sim --scene corridor --mount handheld --lidar avia --raw --frames 100 --out walks/corridor0

Frames are 10 Hz sweeps (``--rate``) with per-point intensity and ring, and the ground-truth pose of
the LiDAR at each scan stamp (start of the sweep). By default every sweep is motion-compensated to
its stamp, as Apollo's compensator publishes it (topic ``.../compensator/PointCloud2``); ``--raw``
writes the sweeps as the driver measures them instead, with a per-point ``time`` field (topic
``/apollo/sensor/velodyne64/PointCloud2``); raw sweeps keep the time field their driver uses (Velodyne
``time``, Ouster ``t``, Livox, Hesai and RoboSense ``timestamp``). Besides the car on the roads, a sensor
can ride a wheeled or legged robot or be carried by hand (``--mount``), indoors, in a courtyard or a
parking garage (``--scene``). The same arguments give bit-identical output. Known errors print one line
and exit with status 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

from deepbbs_ros.cli.common import HelpFormatter, cli_entry

SCENES = ("urban", "suburban", "highway", "open_road")  # = deepbbs_ros.sim.SCENES (kept import-free)
PLACES = ("corridor", "hall", "courtyard", "garage")  # = deepbbs_ros.sim.places.PLACES
FORMATS = ("apollo", "kitti", "mcap", "db3")
PRESETS = ("hdl64", "hdl32", "vlp16", "ouster64", "os0_32", "os0_64", "os0_128", "os1_32", "os1_64", "os1_128",
           "xt32", "helios32", "avia", "mid360")  # = deepbbs_ros.sim.patterns.SENSORS
SOLID_STATE = ("avia", "mid360")
MOUNTS = ("car", "wheeled", "legged", "handheld")  # = deepbbs_ros.sim.mounts.MOUNTS


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="deepbbs-sim", description=__doc__.split("\n\n")[0],
                                     formatter_class=HelpFormatter)
    g = parser.add_argument_group("drive")
    g.add_argument("--scene", choices=SCENES + PLACES, default="urban",
                   help="roads (urban, suburban, highway, open_road) or places: corridor (office corridor loop), "
                        "hall, courtyard (campus square), garage (parking level) (default: urban)")
    g.add_argument("--mount", choices=MOUNTS, default="car",
                   help="what carries the sensor: car (roof), wheeled (ground robot 0.3-1 m high, turns in place), "
                        "legged (quadruped, sway and bob), handheld (tilted down, glancing aside) (default: car)")
    g.add_argument("--seed", type=int, default=0, help="random seed; same seed -> same drive (default: 0)")
    g.add_argument("--frames", type=int, default=100, metavar="N", help="number of frames (default: 100)")
    g.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="spin / frame rate (default: 10)")
    g = parser.add_argument_group("sensor")
    g.add_argument("--lidar", choices=PRESETS, default="hdl64",
                   help="sensor preset: Velodyne hdl64 / hdl32 / vlp16, Ouster ouster64 and os0_* / os1_* (32, 64, "
                        "128 beams), Hesai xt32, RoboSense-like helios32, Livox avia / mid360 (non-repetitive) "
                        "(default: hdl64)")
    g.add_argument(
        "--beams", type=int, default=None, metavar="N",
        help="keep N of the preset's beams, evenly spread over its field of view (decimation) (default: all of them)",
    )
    preset = " (default: the --lidar preset's)"
    g.add_argument("--azimuth-step", type=float, default=None, metavar="DEG",
                   help="azimuth resolution in degrees" + preset)
    g.add_argument("--max-range", type=float, default=None, metavar="M", help="maximum range in metres" + preset)
    g.add_argument("--range-noise", type=float, default=None, metavar="M", help="range noise sigma in metres" + preset)
    g.add_argument("--dropout", type=float, default=None, metavar="P", help="probability of a lost return" + preset)
    g.add_argument("--mount-height", type=float, default=None, metavar="M",
                   help="sensor height above the road, car mount only" + preset)
    g.add_argument("--mount-pitch", type=float, default=None, metavar="DEG",
                   help="nose-down sensor tilt, car and wheeled mounts" + preset)
    g.add_argument(
        "--no-motion-distortion", action="store_true",
        help="cast the whole sweep from the pose at the stamp (default: each column from its own pose)",
    )
    g.add_argument(
        "--raw", action="store_true",
        help="write raw sweeps (motion-distorted, per-point time field) instead of compensated ones",
    )
    g = parser.add_argument_group("output")
    g.add_argument("--format", choices=FORMATS, default="mcap", help="output format (default: mcap rosbag2)")
    g.add_argument("--driver-layout", action="store_true",
                   help="with --raw and mcap / db3: write the clouds in the sensor driver's own PointCloud2 layout "
                        "(velodyne_pointcloud, ouster-ros (organised), livox_ros_driver2, HesaiLidar_ROS_2.0; not "
                        "for helios32) instead of a packed one")
    g.add_argument("--out", required=True, metavar="PATH", help="output directory (must not exist, or be empty)")
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="simulate frames in N processes (car drives on roads; others use one) (default: 1)")
    g.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    return parser


def make_lidar(args: argparse.Namespace):
    """The LiDAR model from a preset plus the command-line overrides."""
    import numpy as np

    from deepbbs_ros.errors import SimulationError
    from deepbbs_ros.sim import LidarConfig

    overrides = {
        "azimuth_step_deg": args.azimuth_step,
        "max_range": args.max_range,
        "range_noise": args.range_noise,
        "dropout": args.dropout,
        "mount_height": args.mount_height,
        "mount_pitch_deg": args.mount_pitch,
    }
    if args.lidar in SOLID_STATE:
        if args.beams is not None or args.azimuth_step is not None:
            raise SimulationError(f"--beams and --azimuth-step do not apply to {args.lidar} (a non-repetitive pattern)")
        from deepbbs_ros.sim.patterns import make_sensor

        lid = make_sensor(args.lidar, **{k: v for k, v in overrides.items() if v is not None})
        lid.validate()
        return lid
    if args.lidar not in PRESETS[:4]:
        from deepbbs_ros.sim.patterns import make_sensor

        lid = make_sensor(args.lidar, **{k: v for k, v in overrides.items() if v is not None})
    else:
        lid = LidarConfig.preset(args.lidar, **{k: v for k, v in overrides.items() if v is not None})
    if args.beams is not None:
        if not 1 <= args.beams <= lid.beams:
            raise SimulationError(f"--beams must be in [1, {lid.beams}] for {args.lidar}, got {args.beams}")
        el = np.rad2deg(lid.elevations())
        keep = np.unique(np.round(np.linspace(0, lid.beams - 1, args.beams)).astype(int))
        lid.elevations_deg = tuple(float(e) for e in el[keep])
        lid.beams = len(keep)
    lid.validate()
    return lid


class _Counted:
    """Iterable wrapper with a length that counts points per frame on the way through."""

    def __init__(self, it, n: int) -> None:
        self._it, self._n = it, n
        self.points = 0
        self.frames = 0

    def __len__(self) -> int:
        return self._n

    def __iter__(self):
        for scan in self._it:
            self.points += len(scan)
            self.frames += 1
            yield scan


@cli_entry("deepbbs-sim")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from deepbbs_ros.datasets import write_scans
    from deepbbs_ros.datasets.base import APOLLO_LIDAR_TOPIC, APOLLO_RAW_LIDAR_TOPIC
    from deepbbs_ros.errors import SimulationError
    from deepbbs_ros.sim import DriveSimulator
    from deepbbs_ros.sim.patterns import driver_fields, driver_of
    from deepbbs_ros.sim.rig import make_simulator
    from deepbbs_ros.sim.simulator import iter_frames

    if args.workers < 1:
        raise SimulationError(f"--workers must be >= 1, got {args.workers}")
    if args.driver_layout and (not args.raw or args.format not in ("mcap", "db3") or args.lidar == "helios32"):
        raise SimulationError("--driver-layout needs --raw, --format mcap or db3, and a sensor other than helios32")
    lidar = make_lidar(args)
    t0 = time.perf_counter()
    sim = make_simulator(args.scene, args.seed, lidar, args.mount, frames=args.frames,
                         motion_distortion=not args.no_motion_distortion, rate_hz=args.rate, compensate=not args.raw)
    if isinstance(sim, DriveSimulator):
        frames = iter_frames(sim, workers=args.workers)
        if args.raw and driver_of(lidar.name) != "velodyne":  # the driver's own time field
            frames = (replace(s, fields=driver_fields(lidar.name, s.fields, s.stamp_ns)) for s in frames)
    else:
        frames = iter(sim)
    counted = _Counted(frames, args.frames)
    topic = APOLLO_RAW_LIDAR_TOPIC if args.raw else APOLLO_LIDAR_TOPIC
    layout: dict = {}
    if args.driver_layout:
        layout = {"driver": "ouster" if args.lidar == "ouster64" else driver_of(lidar.name)}
        if layout["driver"] == "ouster":
            layout["shape"] = (lidar.beams, lidar.columns)
    n = write_scans(counted, args.out, args.format, topic=topic, progress=not args.quiet, **layout)
    wall = time.perf_counter() - t0
    if not args.quiet:
        from rich.console import Console
        from rich.table import Table

        dist = float(sum(
            ((sim.pose_at(k + 1)[:3, 3] - sim.pose_at(k)[:3, 3]) ** 2).sum() ** 0.5 for k in range(args.frames - 1)
        ))
        table = Table(title=f"deepbbs-sim: {args.scene} seed {args.seed} -> {args.out} ({args.format})")
        table.add_column("quantity")
        table.add_column("value", justify="right")
        table.add_column("unit")
        table.add_row("frames written", str(n), "frames")
        if args.lidar in SOLID_STATE:
            table.add_row("LiDAR", f"{lidar.name}, {lidar.lines} lines, {lidar.points_per_s:.0f} points/s", "")
        else:
            table.add_row("LiDAR", f"{lidar.name}, {lidar.beams} beams x {lidar.columns} columns", "")
        table.add_row("mount", args.mount, "")
        table.add_row("output", "raw sweeps (per-point time)" if args.raw else "motion-compensated to the stamp", "")
        table.add_row("mean points per frame", f"{counted.points / max(counted.frames, 1):.0f}", "points")
        table.add_row("distance driven", f"{dist:.1f}", "m")
        table.add_row("wall time (simulate + write)", f"{wall:.1f}", "s")
        table.add_row("throughput", f"{n / wall:.2f}", "frames/s")
        Console(file=sys.stderr).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
