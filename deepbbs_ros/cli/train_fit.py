"""``deepbbs-train fit``: train (or resume) a model on cache folders, alone or as one process of ``torchrun``
(deepbbs_ros/train/trainer.py does the work)."""

from __future__ import annotations

import gc
import json
import shlex
import sys
from pathlib import Path

from deepbbs_ros.cli.train_parser import _config, _overrides
from deepbbs_ros.errors import ConfigError
from deepbbs_ros.train.run_log import STATE_FILE


def run_fit(args) -> int:
    from deepbbs_ros.train import distributed

    if distributed.env_world_size() <= 1:
        return _fit(args, main_rank=True)
    # torchrun: join the process group first (the device of this rank decides gloo or NCCL)
    args.device = distributed.init_from_env(args.device or _config(args).registration.device)
    try:
        code = _fit(args, main_rank=distributed.world()[0] == 0)
        # the trainer's DistributedDataParallel goes now, not at the interpreter's exit (rank 0's sat in a reference
        # cycle): its reducer holds the process group, which destroy() below must end while the interpreter is whole
        gc.collect()
        distributed.barrier()  # leave the group together: rank 0 may still be writing the run when the others end
        return code
    finally:
        distributed.destroy()


def _fit(args, main_rank: bool) -> int:
    from deepbbs_ros.config import Config
    from deepbbs_ros.train.cache import load_cache
    from deepbbs_ros.train.trainer import Trainer

    run = Path(args.run)
    saved_args = run / "fit_args.json"
    if args.resume is not None:
        if not (Path(args.resume) if args.resume else run / STATE_FILE).exists():
            raise ConfigError(f"--resume: no training state in {args.resume or run / STATE_FILE}")
        if saved_args.exists():  # data and config of the run unless given again
            prev = json.loads(saved_args.read_text())
            args.cache = args.cache or prev.get("cache", [])
            args.val_cache = args.val_cache or prev.get("val_cache", [])
            args.config = args.config or prev.get("config")
            # each key once, at its first place with its last value (what _overrides makes of the list): a schedule
            # resuming with its whole --set list again records it once, and the run's command stays reproducible
            args.set = list({s.partition("=")[0].strip(): s for s in prev.get("set", []) + list(args.set)}.values())
            args.init = None
    if not args.cache:
        raise ConfigError("fit: give --cache FOLDER (build one with 'deepbbs-train cache')")
    cfg = _config(args)
    if args.resume is not None and not any(k.startswith("model.") for k in _overrides(args.set)):
        # the run's own network, even if the package's default ModelConfig changed since it started
        cfg = Config.from_dict({**cfg.to_dict(), "model": _state_model_config(args.resume or run / STATE_FILE)})
    model = None
    meta = {"command": "deepbbs-train " + shlex.join(sys.argv[1:]), "cache": args.cache, "val_cache": args.val_cache}
    if args.init:
        from deepbbs_ros.core.checkpoint import default_weights_path, load_checkpoint

        model, init_cfg, _ = load_checkpoint(default_weights_path() if args.init == "shipped" else args.init)
        cfg = Config.from_dict({**cfg.to_dict(), "model": init_cfg.to_dict()["model"]})
        meta["init"] = str(args.init)
    train_drives = load_cache(args.cache)
    val_drives = load_cache(args.val_cache) if args.val_cache else None
    meta["data"] = _describe(train_drives)
    if val_drives:
        meta["val_data"] = _describe(val_drives)
    trainer = Trainer(cfg, run, train_drives, val_drives, device=args.device, model=model,
                      progress=not args.no_progress, meta=meta)
    if args.resume is not None:
        step = trainer.resume(args.resume or None)
        if main_rank:
            print(f"deepbbs-train: resumed {run} at step {step} (epoch {trainer.epoch})", file=sys.stderr)
    if main_rank:
        saved_args.write_text(json.dumps({"cache": args.cache, "val_cache": args.val_cache, "config": args.config,
                                          "set": args.set}, indent=2))
    max_steps = args.max_steps
    if args.until_epoch is not None:
        left = args.until_epoch * cfg.train.steps_per_epoch - trainer.step
        max_steps = left if max_steps is None else min(max_steps, left)
        if left <= 0:
            if main_rank:
                print(f"deepbbs-train: epoch {args.until_epoch} already reached", file=sys.stderr)
            return 0
    budget = None if args.time_budget_min is None else 60.0 * args.time_budget_min
    procs = f", {trainer.world_size} processes" if trainer.world_size > 1 else ""
    if main_rank:
        print(f"deepbbs-train: {len(train_drives)} training drives ({trainer.sampler.num_pairs} frame pairs), "
              f"{len(val_drives or [])} validation drives, device {trainer.device}{procs}, run {run}",
              file=sys.stderr)
    res = trainer.fit(max_steps=max_steps, time_budget_s=budget)
    if not main_rank:
        return 0
    best = res.get("best_val")
    print(f"deepbbs-train: stopped at step {res['step']} (epoch {res['epoch']}), "
          f"{res['train_seconds'] / 60:.1f} min of training; checkpoints in {run}")
    if best:
        from deepbbs_ros.train.validation import format_val

        print("best " + format_val(best))
    return 0


def _state_model_config(path) -> dict:
    import torch

    from deepbbs_ros.errors import ModelError

    path = Path(path)
    if path.is_dir():
        path = path / STATE_FILE
    try:
        return torch.load(path, map_location="cpu", weights_only=False)["config"]["model"]
    except Exception as err:  # noqa: BLE001 - any unpickling failure means a corrupt file
        raise ModelError(f"resume: {path} is not a readable training state ({err})") from err


def _describe(drives) -> dict:
    scenes: dict[str, int] = {}
    frames = 0
    for d in drives:
        scenes[d.scene] = scenes.get(d.scene, 0) + 1
        frames += len(d)
    seeds = sorted(int(d.meta["seed"]) for d in drives if "seed" in d.meta)
    out = {"drives": len(drives), "frames": frames, "scenes": scenes}
    if seeds:
        out["seeds"] = [seeds[0], seeds[-1]]
    return out
