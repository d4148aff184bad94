"""A training run's checkpoints: ``state_latest.pt``, everything an exact resume needs (model, optimiser,
scheduler, step, every generator, history, best score; with several processes every rank's generators), the
weights in the shipped checkpoint format (``model_latest.pt``, ``model_best.pt``, ``val_best.json``), and the
resume that restores a :class:`~deepbbs_ros.train.trainer.Trainer` from them.

The trainer imports this module, not the other way: what is saved and restored is named by :class:`TrainerState`, the
attributes read and set here (the folder's file names are run_log.py's)."""

from __future__ import annotations

import json
import random
import sys
import time
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ModelError
from deepbbs_ros.train.run_log import BEST_MODEL, LATEST_MODEL, STATE_FILE, truncate_log

__all__ = ["BEST_MODEL", "LATEST_MODEL", "STATE_FILE", "TrainerState", "model_meta", "rank_state", "restore_state",
           "save_state"]


class TrainerState(Protocol):
    """What a training state holds of :class:`deepbbs_ros.train.trainer.Trainer` (read when saved, set on resume)."""

    config: Config
    run_dir: Path
    meta: dict[str, Any]
    model: Any  # torch.nn.Module
    optimizer: Any  # torch.optim.Optimizer
    scheduler: Any  # torch.optim.lr_scheduler.LRScheduler
    device: Any  # torch.device
    rng: np.random.Generator
    step: int
    train_seconds: float
    best_score: float | None
    best_val: dict[str, Any] | None
    history: list[dict[str, Any]]
    rank: int
    world_size: int
    is_main: bool
    num_points: int
    sp_anchor: dict[str, Any] | None  # L2-SP's start weights (train/anchor.py), None when train.sp_weight is 0

    @property
    def epoch(self) -> int: ...


def model_meta(trainer: TrainerState, val: dict[str, Any] | None) -> dict[str, Any]:
    """The metadata stored in a model checkpoint: the trainer's, its progress and the validation ``val``."""
    return {**trainer.meta, "step": trainer.step, "epoch": trainer.epoch,
            "train_seconds": round(trainer.train_seconds, 1), "num_points": trainer.num_points, "validation": val,
            "saved_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def rank_state(trainer: TrainerState) -> dict[str, Any]:
    """This process's generators and a digest of its weights (the same on every rank when in sync)."""
    import hashlib

    import torch

    digest = hashlib.sha256()
    for v in trainer.model.state_dict().values():
        digest.update(v.detach().cpu().contiguous().numpy().tobytes())
    return {"rank": trainer.rank, "np_rng": trainer.rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state(trainer.device) if trainer.device.type == "cuda" else None,
            "py_rng": random.getstate(), "weights_sha256": digest.hexdigest()}


def save_state(trainer: TrainerState, val: dict[str, Any] | None = None, best: bool = False) -> None:
    """Write ``state_latest.pt`` and ``model_latest.pt`` (and ``model_best.pt`` when ``best``).
    With several processes every rank calls it (their generators are gathered); rank 0 writes."""
    import torch

    from deepbbs_ros.core.checkpoint import save_checkpoint

    ranks = None
    if trainer.world_size > 1:
        from deepbbs_ros.train.distributed import all_gather

        ranks = all_gather(rank_state(trainer))
        if not trainer.is_main:
            return
    state = {
        "format": "deepbbs_ros.train/1",
        "model": trainer.model.state_dict(),
        "optimizer": trainer.optimizer.state_dict(),
        "scheduler": trainer.scheduler.state_dict(),
        "step": trainer.step,
        "train_seconds": trainer.train_seconds,
        "np_rng": trainer.rng.bit_generator.state,
        "torch_rng": torch.get_rng_state(),
        "cuda_rng": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
        "py_rng": random.getstate(),
        "best_score": trainer.best_score,
        "best_val": trainer.best_val,
        "history": trainer.history,
        "config": trainer.config.to_dict(),
        "meta": trainer.meta,
        "world_size": trainer.world_size,
        "ranks": ranks,
        "sp_anchor": trainer.sp_anchor,
    }
    run_dir = trainer.run_dir
    tmp = run_dir / (STATE_FILE + ".tmp")
    torch.save(state, tmp)
    tmp.replace(run_dir / STATE_FILE)
    last_val = val or next((h for h in reversed(trainer.history) if h.get("kind") == "val"), None)
    save_checkpoint(run_dir / LATEST_MODEL, trainer.model, trainer.config, model_meta(trainer, last_val))
    if best:
        save_checkpoint(run_dir / BEST_MODEL, trainer.model, trainer.config, model_meta(trainer, val))
        (run_dir / "val_best.json").write_text(json.dumps(model_meta(trainer, val), indent=2))


def restore_state(trainer: TrainerState, path: str | Path | None = None) -> int:
    """Restore everything from ``state_latest.pt`` (or ``path``) into ``trainer``. Returns the step reached."""
    import torch

    path = Path(path) if path else trainer.run_dir / STATE_FILE
    if path.is_dir():
        path = path / STATE_FILE
    if not path.exists():
        raise ModelError(f"resume: no training state at {path}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means a corrupt file
        raise ModelError(f"resume: {path} is not a readable training state ({err})") from err
    if state.get("format") != "deepbbs_ros.train/1":
        raise ModelError(f"resume: {path} is not a deepbbs-train state file")
    saved_model = state["config"]["model"]
    if saved_model != trainer.config.to_dict()["model"]:
        raise ModelError(f"resume: {path} was trained with a different model config ({saved_model})")
    trainer.model.load_state_dict(state["model"])
    if trainer.sp_anchor is not None:  # L2-SP: the saved start, else the weights resumed with
        from deepbbs_ros.train.anchor import anchor_of

        trainer.sp_anchor = state.get("sp_anchor") or anchor_of(trainer.model)
    trainer.optimizer.load_state_dict(state["optimizer"])
    trainer.scheduler.load_state_dict(state["scheduler"])
    trainer.step = int(state["step"])
    trainer.train_seconds = float(state.get("train_seconds", 0.0))
    trainer.rng.bit_generator.state = state["np_rng"]
    torch.set_rng_state(state["torch_rng"])
    if state.get("cuda_rng") is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda_rng"])
    random.setstate(state["py_rng"])
    saved_world = int(state.get("world_size") or 1)
    ranks = state.get("ranks") or []
    if trainer.world_size > 1:
        if trainer.rank < len(ranks):  # this rank's own generators
            mine = ranks[trainer.rank]
            trainer.rng.bit_generator.state = mine["np_rng"]
            torch.set_rng_state(mine["torch_rng"])
            if mine.get("cuda_rng") is not None and trainer.device.type == "cuda":
                torch.cuda.set_rng_state(mine["cuda_rng"], trainer.device)
            random.setstate(mine["py_rng"])
        else:  # a rank the saved run did not have: a fresh generator of its own
            trainer.rng = np.random.default_rng([trainer.config.train.seed, trainer.rank, trainer.step])
    if saved_world != trainer.world_size and trainer.is_main:
        print(f"deepbbs-train: resuming a state saved by {saved_world} process(es) with {trainer.world_size}: "
              "weights, optimiser and schedule continue, the order of the pairs differs", file=sys.stderr)
    trainer.best_score = state.get("best_score")
    trainer.best_val = state.get("best_val")
    trainer.history = list(state.get("history", []))
    if trainer.is_main:
        truncate_log(trainer.run_dir, trainer.step)
    return trainer.step
