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
resumes where it stopped. Simulated drives are made by :mod:`deepbbs_ros.train.sim_cache`, users'
recordings here (:func:`cache_recording`).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Sequence
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


def check_disjoint_seeds(*groups: Iterable[int]) -> None:
    """Raise :class:`DatasetError` if two seed groups (train / val / test) share a seed."""
    seen: dict[int, int] = {}
    for gi, group in enumerate(groups):
        for s in group:
            if s in seen and seen[s] != gi:
                raise DatasetError(f"training cache: scene seed {s} is used by two splits (train/val/test)")
            seen[s] = gi


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
