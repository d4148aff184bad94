"""Simulated drives for the training cache: the randomised road LiDAR, the drive specs (scene, seed,
sensor, mount, frame stride, sweep output) and their simulation into ``<cache>/<name>.npz`` files.

Everything a drive draws (sensor, sweep output, scene) comes from its seed, so a cache is
reproducible from its seeds alone. The file format is :mod:`deepbbs_ros.train.cache`'s.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.train.cache import cache_frame, save_drive

# frames of a drive are at most this many sweeps apart (SimDriveSpec.min_span): 1 s at 10 Hz, so that neighbouring
# frames of a slow mount still overlap
MAX_FRAME_STRIDE = 10


# -- simulated drives ---------------------------------------------------------------------------
def random_lidar(rng: np.random.Generator) -> tuple[Any, dict[str, Any]]:
    """A randomised sensor: model (64/32/16 beams, Ouster-like), beam angles, noise, dropouts,
    mounting height and tilt. Returns the ``LidarConfig`` and a JSON-friendly description."""
    from deepbbs_ros.sim import LidarConfig

    presets = [("hdl64", 0.35), ("ouster64", 0.25), ("hdl32", 0.25), ("vlp16", 0.15)]
    names, probs = zip(*presets)
    name = str(rng.choice(names, p=np.asarray(probs) / sum(probs)))
    base = getattr(LidarConfig, name)()
    fields = {f.name for f in dataclasses.fields(base)}
    changes: dict[str, Any] = {}

    def maybe(key: str, value: Any) -> None:
        if key in fields:
            changes[key] = value

    # beam angles: shift and stretch the vertical field of view a little
    shift, stretch = float(rng.uniform(-1.5, 1.5)), float(rng.uniform(0.9, 1.1))
    if getattr(base, "elevations_deg", ()):  # explicit beam table (HDL-64): stretch and shift it
        elev = np.asarray(base.elevations_deg, dtype=np.float64)
        mid = 0.5 * (elev.min() + elev.max())
        changes["elevations_deg"] = tuple(float(e) for e in mid + shift + (elev - mid) * stretch)
    elif "vfov_min_deg" in fields and "vfov_max_deg" in fields:
        lo, hi = float(base.vfov_min_deg), float(base.vfov_max_deg)
        mid = 0.5 * (lo + hi) + shift
        half = 0.5 * (hi - lo) * stretch
        changes["vfov_min_deg"], changes["vfov_max_deg"] = mid - half, mid + half
    if "azimuth_step_deg" in fields:
        changes["azimuth_step_deg"] = float(base.azimuth_step_deg) * rng.uniform(0.9, 1.6)
    maybe("range_noise", float(rng.uniform(0.005, 0.04)))
    maybe("dropout", float(rng.uniform(0.0, 0.15)))
    maybe("mount_height", float(rng.uniform(1.5, 2.4)))
    for key in ("mount_pitch_deg", "tilt_deg", "pitch_deg"):
        maybe(key, float(rng.uniform(-3.0, 3.0)))
    for key in ("mount_roll_deg", "roll_deg"):
        maybe(key, float(rng.uniform(-1.5, 1.5)))
    lidar = dataclasses.replace(base, **changes)
    desc = {"preset": name, "vfov_shift_deg": round(shift, 3), "vfov_stretch": round(stretch, 3),
            **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in changes.items() if k != "elevations_deg"}}
    return lidar, desc


@dataclass
class SimDriveSpec:
    """One simulated drive of the cache.

    scene: a road scene or a place (``deepbbs_ros.sim.rig.ALL_PLACES``); sensor: a preset name
    (``deepbbs_ros.sim.patterns.SENSORS``), or None for the randomised road sensors (:func:`random_lidar`);
    mount: ``deepbbs_ros.sim.mounts.MOUNTS``. Left at None / ``"car"`` on a road scene the drive is the one
    the cache has always made.
    """

    scene: str
    seed: int
    frames: int
    sensor: str | None = None
    mount: str = "car"
    # m; 0: the frames are consecutive (10 Hz). Else the frames are every s-th sweep, s the smallest stride
    # (at most MAX_FRAME_STRIDE) whose frames span this path length: a slow mount (handheld, legged, wheeled at
    # 0.5-1.5 m/s) then has pairs as far apart as a car's, up to train.max_dist (the road drives keep stride 1)
    min_span: float = 0.0
    # "mixed": the drive's seed draws its sweeps (half compensated to the stamp, 30 % raw, 20 % ideal); "compensated":
    # every sweep motion-distorted, then compensated to its stamp, so that the ground truth at the stamp is its label
    sweeps: str = "mixed"

    @property
    def name(self) -> str:
        if self.sensor is None and self.mount == "car":
            return f"{self.scene}_{self.seed}"
        return f"{self.scene}_{self.mount}_{self.sensor or 'random'}_{self.seed}"


def sim_drive_specs(scenes: Sequence[str], seeds: Sequence[int], frames: int, *,
                    sensors: Sequence[str] | None = None, mounts: Sequence[str] | None = None,
                    min_span: float = 0.0, sweeps: str = "mixed") -> list[SimDriveSpec]:
    """Drives for ``seeds``, the scene types cycling over ``scenes`` (seed i -> scenes[i % len]).

    sensors / mounts: when given, each drive draws one of them from its seed (``"random"`` in sensors =
    the randomised road sensors); left out, every drive is a car with a randomised road sensor, as before.
    min_span, sweeps: :attr:`SimDriveSpec.min_span` and :attr:`SimDriveSpec.sweeps` of every drive.
    """
    from deepbbs_ros.sim.mounts import MOUNTS
    from deepbbs_ros.sim.patterns import SENSORS

    for name in sensors or ():
        if name != "random" and name not in SENSORS:
            raise DatasetError(f"training cache: unknown sensor {name!r}; choose from random, {', '.join(SENSORS)}")
    for name in mounts or ():
        if name not in MOUNTS:
            raise DatasetError(f"training cache: unknown mount {name!r}; choose from {', '.join(MOUNTS)}")
    if sweeps not in ("mixed", "compensated"):
        raise DatasetError(f"training cache: sweeps must be 'mixed' or 'compensated', got {sweeps!r}")
    specs = []
    for i, s in enumerate(seeds):
        spec = SimDriveSpec(scenes[i % len(scenes)], int(s), int(frames), min_span=float(min_span), sweeps=sweeps)
        if sensors or mounts:
            pick = np.random.default_rng([int(s), 7920])
            sensor = str(pick.choice(list(sensors))) if sensors else "random"
            spec.sensor = None if sensor == "random" else sensor
            spec.mount = str(pick.choice(list(mounts))) if mounts else "car"
        specs.append(spec)
    return specs


def simulate_cached_drive(spec: SimDriveSpec, out_dir: Path, pre: PreprocessConfig, cache_points: int,
                          randomize_sensor: bool = True) -> Path:
    """Simulate one drive, preprocess every frame and write ``<out_dir>/<scene>_<seed>.npz``.

    The sensor (when randomised) and the sweep output are drawn from the scene seed, so a cache is
    reproducible from its seeds alone. Outputs: half the drives are motion-compensated to the stamp
    (what Apollo's compensator, or the pipeline's deskew, delivers), 30 % raw sweeps (what the network
    sees before the deskew stage: points measured along the sweep, ground truth at the stamp), 20 %
    ideal instantaneous scans.
    """
    from deepbbs_ros.sim import LidarConfig, simulate_drive

    path = Path(out_dir) / f"{spec.name}.npz"
    rng = np.random.default_rng([spec.seed, 7919])
    if spec.sensor is not None:  # a named preset (solid-state ones included), as its datasheet gives it
        from deepbbs_ros.sim.patterns import make_sensor

        lidar, desc = make_sensor(spec.sensor), {"preset": spec.sensor}
        u = float(rng.random())
        motion, compensate = u < 0.8, u < 0.5
    elif randomize_sensor:
        lidar, desc = random_lidar(rng)
        u = float(rng.random())
        motion, compensate = u < 0.8, u < 0.5
    else:
        lidar, desc, motion, compensate = LidarConfig.hdl64(), {"preset": "hdl64"}, True, True
    if spec.sweeps == "compensated":  # the seed's draws above stay as they were: same sensor, same scene
        motion, compensate = True, True
    from deepbbs_ros.sim.scene import SCENES

    # the road drives the cache has always made; a car in a garage or a courtyard goes through the rig
    if spec.sensor is None and spec.mount == "car" and spec.scene in SCENES:
        scans = simulate_drive(spec.scene, spec.seed, spec.frames, lidar=lidar, motion_distortion=motion,
                               compensate=compensate)
    else:
        from deepbbs_ros.sim.rig import make_simulator

        longest = spec.frames * (MAX_FRAME_STRIDE if spec.min_span > 0 else 1)
        sim = make_simulator(spec.scene, spec.seed, lidar, spec.mount, frames=longest,
                             motion_distortion=motion, compensate=compensate)
        stride = frame_stride(sim, spec.frames, spec.min_span)
        scans = (sim.scan_at(k * stride) for k in range(spec.frames))
        desc = {**desc, "mount": spec.mount, **({"frame_stride": stride} if spec.min_span > 0 else {})}
    frames, poses, stamps, raw_counts = [], [], [], []
    t0 = time.perf_counter()
    for k, scan in enumerate(scans):
        frames.append(cache_frame(scan.points, pre, cache_points, seed=spec.seed * 1000 + k))
        poses.append(scan.T_world_lidar)
        stamps.append(scan.stamp_ns)
        raw_counts.append(len(scan.points))
    meta = {
        "kind": "sim", "scene": spec.scene, "seed": spec.seed, "frames": spec.frames, "sensor": desc,
        "motion_distortion": motion, "compensated": compensate, "preprocess": dataclasses.asdict(pre),
        "cache_points": cache_points,
        "raw_points_mean": float(np.mean(raw_counts)) if raw_counts else 0.0,
        "seconds": round(time.perf_counter() - t0, 2),
    }
    save_drive(path, frames, np.stack(poses), stamps, meta)
    return path


def frame_stride(sim: Any, frames: int, min_span: float) -> int:
    """The smallest stride s (1..MAX_FRAME_STRIDE) whose ``frames`` frames 0, s, 2s, ... of ``sim`` (a simulator
    with ``pose_at``, at least ``frames * MAX_FRAME_STRIDE`` frames long when min_span > 0) travel ``min_span`` m
    along the ground-truth path; 1 when ``min_span`` is 0. Poses only: no ray is cast."""
    if min_span <= 0:
        return 1
    pos = np.stack([sim.pose_at(k)[:3, 3] for k in range(frames * MAX_FRAME_STRIDE)])
    step = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    for s in range(1, MAX_FRAME_STRIDE + 1):
        if step[(frames - 1) * s] >= min_span:
            return s
    return MAX_FRAME_STRIDE


def build_sim_cache(out_dir: str | Path, specs: Sequence[SimDriveSpec], pre: PreprocessConfig, cache_points: int,
                    *, randomize_sensor: bool = True, progress: bool = True) -> Iterator[Path]:
    """Simulate the missing drives of ``specs`` into ``out_dir`` (existing files are kept)."""
    from tqdm import tqdm

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    todo = [s for s in specs if not (out_dir / f"{s.name}.npz").exists()]
    bar = tqdm(total=sum(s.frames for s in todo), unit="frames", desc=f"cache {out_dir.name}", disable=not progress)
    for spec in todo:
        bar.set_postfix_str(spec.name)
        path = simulate_cached_drive(spec, out_dir, pre, cache_points, randomize_sensor)
        bar.update(spec.frames)
        yield path
    bar.close()
