"""Adapting the shipped network to a user's recording, without ground truth (``deepbbs-train adapt``).

1. read the recording once (any source ``deepbbs-replay`` reads): per scan the pipeline's preprocessing (for
   registering) and a denser training cloud (``cache_frame``, the sensor's preprocessing settings);
2. split it by time (:func:`pseudo.split_frames`): adaptation part, gap, held-back part;
3. pseudo-labels on the adaptation part (:mod:`deepbbs_ros.train.pseudo`): pairs at several strides registered by
   the shipped pipeline, kept when the verdict accepts them and their triplets agree;
4. fine-tune with the training loss on those pairs (:class:`LabelSampler`: fresh samplings, crops, noise and a
   random start yaw / shift each step, so the network learns the basin around the label, not the label's start),
   resumable (:class:`deepbbs_ros.train.trainer.Trainer`);
5. the before / after report on the held-back scans (:mod:`deepbbs_ros.train.adapt_report`).

The recording's poses are read only for the report (``Recording.T_world_lidar``); nothing in 3-4 receives them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError, DatasetError
from deepbbs_ros.train.augment import AugmentConfig, augment_pair
from deepbbs_ros.train.cache import Drive
from deepbbs_ros.train.pairs import Pair
from deepbbs_ros.train.pseudo import Labels, candidate_pairs, cycle_consistency, label_quality, register_pairs

LABELS_FILE = "labels.npz"
ADAPTED_MODEL = "model_adapted.pt"


@dataclass
class Recording:
    """A recording read for adaptation. ``frames``: training clouds (P_f, 3) float32; ``prepared``: the pipeline's
    ``PreprocessResult`` per scan; ``T_world_lidar`` (F, 4, 4) or None: poses, for the report only."""

    source: str
    frames: list[np.ndarray]
    prepared: list[Any]
    stamps_ns: np.ndarray
    T_world_lidar: np.ndarray | None

    def __len__(self) -> int:
        return len(self.frames)

    def drive(self) -> Drive:
        """The training clouds as a drive without poses."""
        counts = [len(f) for f in self.frames]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        return Drive("adapt", np.concatenate(self.frames).astype(np.float32), offsets, None, self.stamps_ns,
                     {"scene": "recording", "source": self.source})


def read_recording(path: str | Path, reg, cache_points: int = 4096, *, topic: str | None = None, every: int = 1,
                   max_frames: int = 0, progress: bool = True) -> Recording:
    """Every ``every``-th scan of ``path`` (at most ``max_frames``), preprocessed by ``reg`` (a
    ``DeepBBSRegistration``) and as a training cloud with the same sensor's settings."""
    from tqdm import tqdm

    from deepbbs_ros.core.scans import with_sensor
    from deepbbs_ros.datasets import open_source
    from deepbbs_ros.train.cache import cache_frame

    src = open_source(path, topic=topic)
    frames, prepared, stamps, poses = [], [], [], []
    bar = tqdm(total=len(src), unit="frames", desc="read", disable=not progress)
    for k, scan in enumerate(src):
        bar.update(1)
        if k % every:
            continue
        pp = with_sensor(reg.config, scan.points).preprocess
        cloud = cache_frame(scan.points, pp, cache_points, seed=k)
        if len(cloud) < 3:
            continue
        frames.append(cloud)
        prepared.append(reg.preprocess(scan.points, scan.point_times(), scan.stamp_ns))
        stamps.append(scan.stamp_ns)
        poses.append(scan.T_world_lidar)
        if max_frames and len(frames) >= max_frames:
            break
    bar.close()
    if len(frames) < 8:
        raise DatasetError(f"adapt: {path} gave {len(frames)} usable scans; adaptation needs at least 8")
    has_poses = all(p is not None for p in poses)
    return Recording(str(path), frames, prepared, np.asarray(stamps, dtype=np.int64),
                     np.stack(poses) if has_poses else None)


class LabelSampler:
    """Draws augmented training pairs from the kept pseudo-labels (the ``Trainer``'s sampler interface: ``batch``,
    ``num_pairs``); a draw depends only on the generator passed in, so a resume continues exactly."""

    def __init__(self, drive: Drive, labels: Labels, aug: AugmentConfig):
        self.drive, self.aug = drive, aug
        keep = np.flatnonzero(labels.kept)
        if not len(keep):
            raise DatasetError("adapt: the pipeline accepted no consistent pair on the adaptation part: nothing to "
                               "learn from (more scans, smaller --strides, or another preprocess.sensor)")
        self.i, self.j, self.T = labels.i[keep], labels.j[keep], labels.T[keep]

    @property
    def num_pairs(self) -> int:
        return int(len(self.i))

    def draw(self, rng: np.random.Generator) -> Pair:
        k = int(rng.integers(len(self.i)))
        i, j = int(self.i[k]), int(self.j[k])
        src, tgt, T = augment_pair(self.drive.frame(i), self.drive.frame(j), self.T[k], rng, self.aug,
                                   self.aug.trans_aug)
        return Pair(src, tgt, T, scene="recording", ref=f"adapt:{i}->{j}")

    def batch(self, rng: np.random.Generator, batch_size: int) -> list[Pair]:
        return [self.draw(rng) for _ in range(batch_size)]


def make_labels(rec: Recording, reg, frames: list[int], strides: list[int], rot_tol_deg: float, trans_tol: float,
                progress: bool = True) -> tuple[Labels, dict[str, int]]:
    """Pseudo-labels of the adaptation ``frames``: the pipeline from identity on each pair, then the triplets."""
    from tqdm import tqdm

    def register(i: int, j: int):
        res = reg.register(rec.prepared[i], rec.prepared[j])
        return res.T_target_source, res.score, res.valid

    pairs = candidate_pairs(frames, strides)
    with tqdm(total=len(pairs), unit="pairs", desc="pseudo-labels", disable=not progress) as bar:
        labels = register_pairs(register, pairs, bar.update)
    return labels, cycle_consistency(labels, rot_tol_deg, trans_tol)


def fine_tune(config: Config, out: Path, rec: Recording, labels: Labels, *, steps: int, resume: bool,
              time_budget_min: float | None, device: str | None, progress: bool, meta: dict[str, Any],
              train_overrides: dict[str, Any] | None = None) -> dict:
    """Fine-tune the shipped network (``registration.weights``) on the kept labels; ``out/model_adapted.pt`` is the
    result (the shipped weights' checkpoint format). The loss and augmentation settings are those the weights were
    trained with (their checkpoint's ``train`` section), but for ``train_overrides`` (``train.*`` keys, the user's
    ``--set``), ``train.lr`` from ``config`` and no learning-rate decay; epochs of up to 50 steps make ``steps``."""
    from deepbbs_ros.core.checkpoint import default_weights_path, load_checkpoint
    from deepbbs_ros.train.run_state import LATEST_MODEL
    from deepbbs_ros.train.trainer import Trainer

    weights = config.registration.weights or str(default_weights_path())
    model, init_cfg, _ = load_checkpoint(weights)
    spe = max(1, min(50, steps))
    epochs = math.ceil(steps / spe)
    train = {**dataclasses.asdict(init_cfg.train),
             **{k.split(".", 1)[1]: v for k, v in (train_overrides or {}).items() if k.startswith("train.")},
             "lr": config.train.lr, "steps_per_epoch": spe, "epochs": epochs, "lr_step": epochs + 1,
             "checkpoint_minutes": config.train.checkpoint_minutes}
    cfg = Config.from_dict({**config.to_dict(), "model": init_cfg.to_dict()["model"], "train": train})
    drive = rec.drive()
    sampler = LabelSampler(drive, labels, AugmentConfig.from_train(cfg.train, cfg.train.num_points
                                                                   or cfg.preprocess.num_points))
    trainer = Trainer(cfg, out, [drive], None, device=device, model=model, progress=progress,
                      meta={**meta, "init": weights, "train_pairs": sampler.num_pairs}, sampler=sampler)
    if resume:
        trainer.resume()
    res = trainer.fit(time_budget_s=None if time_budget_min is None else 60.0 * time_budget_min)
    shutil.copyfile(out / LATEST_MODEL, out / ADAPTED_MODEL)
    return {"steps": res["step"], "train_seconds": round(res["train_seconds"], 1),
            "s_per_step": round(res["train_seconds"] / max(1, res["step"]), 3)}


def label_summary(rec: Recording, labels: Labels, counts: dict[str, int]) -> dict[str, Any]:
    """The counts of :func:`cycle_consistency`, graded against the recording's poses when it has any."""
    out: dict[str, Any] = dict(counts)
    if rec.T_world_lidar is not None:
        out["against_poses"] = label_quality(labels, rec.T_world_lidar)
    return out


def check_out(out: Path, resume: bool) -> None:
    """A fresh folder for a new adaptation; the previous one's for ``--resume``."""
    from deepbbs_ros.train.run_state import STATE_FILE

    if resume and not (out / STATE_FILE).exists():
        raise ConfigError(f"adapt --resume: no adaptation state in {out}")
    if not resume and (out / STATE_FILE).exists():
        raise ConfigError(f"adapt: {out} holds an adaptation already; continue it with --resume or give another --out")
    out.mkdir(parents=True, exist_ok=True)


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps({**data, "written_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}, indent=2))
