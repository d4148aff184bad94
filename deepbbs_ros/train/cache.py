"""A frame cache for training: every drive is preprocessed ONCE into one ``.npz`` file.

Ray casting a 120k-point scan and removing its ground costs far more than a training step's data
preparation, so scans are simulated (or read from a user's recording) once, reduced to the
non-ground, voxelised points the registration sees (capped by farthest-point sampling at
``cache_points``), and stored with their ground-truth pose. Training steps then only sample pairs,
augment and down-sample from memory.

File layout (``<cache>/<name>.npz``, one per drive):

* ``points``: (P_total, 3) float32, the frames' points concatenated, sensor frame, metres;
* ``offsets``: (F + 1,) int64, frame ``f`` is ``points[offsets[f]:offsets[f + 1]]``;
* ``T_world_lidar``: (F, 4, 4) float64 ground-truth poses (NaN-filled when the drive has none);
* ``stamps_ns``: (F,) int64;
* ``meta``: a JSON string (scene, seed, sensor settings, source path, preprocessing, has_gt).

A drive is written to ``<name>.npz.tmp`` and renamed when complete, so an interrupted cache build
resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import PreprocessConfig
from deepbbs_ros.errors import DatasetError, RegistrationError

# Scene seeds are split into disjoint ranges so that validation and evaluation never see a
# training scene (checked by :func:`check_disjoint_seeds`).
TRAIN_SEED_BASE = 10_000
VAL_SEED_BASE = 80_000
TEST_SEED_BASE = 90_000
# frames of a drive are at most this many sweeps apart (SimDriveSpec.min_span): 1 s at 10 Hz, so that neighbouring
# frames of a slow mount still overlap
MAX_FRAME_STRIDE = 10


@dataclass
class Drive:
    """One cached drive (or recording): preprocessed frames and their poses.

    Attributes:
        name: file stem, e.g. ``urban_10003``.
        points: (P_total, 3) float32 concatenated frames, sensor frame, metres.
        offsets: (F + 1,) int64 frame boundaries into ``points``.
        T_world_lidar: (F, 4, 4) float64 poses, or None when the recording has no ground truth.
        meta: scene, seed, sensor settings, preprocessing (JSON-friendly).
    """

    name: str
    points: np.ndarray
    offsets: np.ndarray
    T_world_lidar: np.ndarray | None
    stamps_ns: np.ndarray
    meta: dict[str, Any]

    def __len__(self) -> int:
        return int(self.offsets.shape[0] - 1)

    def frame(self, f: int) -> np.ndarray:
        """(P_f, 3) float32 points of frame ``f`` (a view, do not modify)."""
        return self.points[self.offsets[f] : self.offsets[f + 1]]

    @property
    def has_gt(self) -> bool:
        return self.T_world_lidar is not None

    @property
    def scene(self) -> str:
        return str(self.meta.get("scene", "recording"))


def save_drive(path: Path, frames: Sequence[np.ndarray], poses: np.ndarray | None, stamps_ns: Sequence[int],
               meta: dict[str, Any]) -> None:
    """Write one drive atomically (``.tmp`` then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    counts = np.array([len(f) for f in frames], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    pts = np.concatenate(frames, axis=0).astype(np.float32) if frames else np.zeros((0, 3), np.float32)
    if poses is None:
        poses_arr = np.full((len(frames), 4, 4), np.nan)
        meta = {**meta, "has_gt": False}
    else:
        poses_arr = np.asarray(poses, dtype=np.float64).reshape(len(frames), 4, 4)
        meta = {**meta, "has_gt": True}
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, points=pts, offsets=offsets, T_world_lidar=poses_arr,
                 stamps_ns=np.asarray(stamps_ns, dtype=np.int64), meta=np.array(json.dumps(meta)))
    tmp.replace(path)


def load_drive(path: str | Path) -> Drive:
    """Read one cached drive; raises :class:`DatasetError` naming the file when it is unreadable."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            poses = z["T_world_lidar"]
            drive = Drive(
                name=path.stem,
                points=np.ascontiguousarray(z["points"], dtype=np.float32),
                offsets=z["offsets"].astype(np.int64),
                T_world_lidar=poses if meta.get("has_gt", True) else None,
                stamps_ns=z["stamps_ns"].astype(np.int64),
                meta=meta,
            )
    except FileNotFoundError as err:
        raise DatasetError(f"training cache: no such file: {path}") from err
    except (OSError, KeyError, ValueError) as err:
        raise DatasetError(f"training cache: {path} is not a valid drive file ({err})") from err
    if len(drive) < 1:
        raise DatasetError(f"training cache: {path} holds no frames")
    return drive


def load_cache(dirs: str | Path | Iterable[str | Path]) -> list[Drive]:
    """All drives (``*.npz``, sorted by name) in one or more cache folders."""
    if isinstance(dirs, (str, Path)):
        dirs = [dirs]
    drives: list[Drive] = []
    for d in dirs:
        d = Path(d)
        if d.is_file():
            drives.append(load_drive(d))
            continue
        if not d.is_dir():
            raise DatasetError(f"training cache: no such folder: {d}")
        files = sorted(d.glob("*.npz"))
        if not files:
            raise DatasetError(f"training cache: {d} holds no drives (*.npz); build it with 'deepbbs-train cache'")
        for f in files:
            drive = load_drive(f)
            drive.meta.setdefault("cache", d.name)  # the folder: validation reports each folder apart
            drives.append(drive)
    return drives


# -- preprocessing of one scan into the cache ------------------------------------------------------
def cache_frame(points: np.ndarray, pre: PreprocessConfig, cache_points: int, seed: int = 0) -> np.ndarray:
    """Raw scan (N, 3) float32 -> cached (P, 3) float32 points, P <= cache_points.

    The same steps as the registration's preprocessing (range crop, ground removal, voxel grid),
    then farthest-point sampling to ``cache_points`` (instead of ``pre.num_points``) so that each
    training step can still draw its own, different, sampling of ``num_points``.
    """
    from deepbbs_ros.core.preprocess import preprocess

    cfg = dataclasses.replace(pre, num_points=int(cache_points))
    try:
        res = preprocess(points, cfg, seed=seed)
    except RegistrationError:
        return np.zeros((0, 3), np.float32)
    # clouds smaller than cache_points come back with repeated FPS indices: keep each point once
    return np.ascontiguousarray(np.unique(res.points, axis=0), dtype=np.float32)


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


def check_disjoint_seeds(*groups: Iterable[int]) -> None:
    """Raise :class:`DatasetError` if two seed groups (train / val / test) share a seed."""
    seen: dict[int, int] = {}
    for gi, group in enumerate(groups):
        for s in group:
            if s in seen and seen[s] != gi:
                raise DatasetError(f"training cache: scene seed {s} is used by two splits (train/val/test)")
            seen[s] = gi


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


# -- users' recordings -------------------------------------------------------------------------
def cache_recording(source_path: str | Path, out_dir: str | Path, pre: PreprocessConfig, cache_points: int, *,
                    topic: str | None = None, gt_topic: str | None = None, every: int = 1,
                    max_frames: int = 0, progress: bool = True, name: str | None = None) -> Path:
    """Preprocess a user's recording (any format ``datasets.open_source`` reads) into the cache.

    With ground truth, training pairs are frames within ``train.max_dist``; without, training is
    self-supervised (two samplings and crops of the same scan under a known random transform).
    """
    from tqdm import tqdm

    from deepbbs_ros.datasets import open_source

    src = open_source(source_path, topic=topic, gt_topic=gt_topic)
    stem = name or Path(str(source_path).rstrip("/")).name.replace(".", "_")
    path = Path(out_dir) / f"rec_{stem}.npz"
    frames, poses, stamps = [], [], []
    has_gt = bool(src.has_ground_truth)
    total = len(src)
    bar = tqdm(total=total, unit="frames", desc=f"cache {stem}", disable=not progress)
    for k, scan in enumerate(src):
        bar.update(1)
        if k % every:
            continue
        pts = cache_frame(scan.points, pre, cache_points, seed=k)
        if len(pts) < 3:
            continue
        if has_gt and scan.T_world_lidar is None:
            continue
        frames.append(pts)
        poses.append(scan.T_world_lidar)
        stamps.append(scan.stamp_ns)
        if max_frames and len(frames) >= max_frames:
            break
    bar.close()
    if not frames:
        raise DatasetError(f"training cache: {source_path} gave no usable frames")
    meta = {"kind": "recording", "scene": "recording", "source": str(source_path), "topic": src.topic,
            "preprocess": dataclasses.asdict(pre), "cache_points": cache_points, "every": every}
    save_drive(path, frames, np.stack(poses) if has_gt else None, stamps, meta)
    return path
