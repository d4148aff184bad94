"""deepbbs-train: build a training cache, train DeepBBS++ (resumable), evaluate weights.

    deepbbs-train cache --out runs/cache/train --split train --drives 64 --frames 25
    deepbbs-train cache --out runs/cache/mine --source my_drive.mcap          # a user's recording
    deepbbs-train fit --cache runs/cache/train --val-cache runs/cache/val --run runs/default
    deepbbs-train fit --run runs/default --resume                              # continue exactly
    deepbbs-train evaluate --weights runs/default/model_best.pt --out runs/default/eval.json
    deepbbs-train report --run runs/default                                    # speed + validation history
    deepbbs-train adapt my_recording.mcap --out runs/adapt                     # learn your sensor, no labels
    torchrun --nproc_per_node 4 $(which deepbbs-train) fit --cache runs/cache/train --run-dir runs/ddp

``fit`` under ``torchrun`` trains with DistributedDataParallel (gloo on a CPU, NCCL with one GPU per
process): train.batch_size pairs per process, gradients averaged, rank 0 writes the run folder.

``fit`` trains on every drive of the ``--cache`` folders (simulated drives and users' recordings
alike; recordings without ground truth train self-supervised) and validates on ``--val-cache``.
"""

from __future__ import annotations

import argparse
import gc
import json
import shlex
import signal
import sys
from pathlib import Path

from deepbbs_ros.cli.common import HelpFormatter, RawHelpFormatter, cli_entry, config_default
from deepbbs_ros.errors import ConfigError


def _seeds(text: str) -> list[int]:
    """``"10000:10064"`` (half-open range) or ``"1,2,7"``."""
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            return list(range(int(a), int(b)))
        return [int(s) for s in text.split(",") if s.strip()]
    except ValueError as err:
        raise ConfigError(f"--seeds: expected 'A:B' or 'S1,S2,...', got {text!r}") from err


def _overrides(items: list[str]) -> dict:
    import yaml

    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--set: expected key=value (e.g. train.epochs=10), got {item!r}")
        parsed = yaml.safe_load(value)
        if isinstance(parsed, str):  # YAML 1.1 reads "1e-3" as a string
            try:
                parsed = float(parsed)
            except ValueError:
                pass
        out[key.strip()] = parsed
    return out


def _config(args):
    from deepbbs_ros.config import load_config

    return load_config(args.config, _overrides(args.set))


def _set_threads(n: int) -> None:
    if n > 0:
        import torch

        torch.set_num_threads(n)


def build_parser() -> argparse.ArgumentParser:
    from deepbbs_ros.sim import SCENES

    head, usage = __doc__.split("\n\n", 1)
    p = argparse.ArgumentParser(prog="deepbbs-train", description=head,
                                formatter_class=RawHelpFormatter, epilog=usage)
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp):
        g = sp.add_argument_group("configuration")
        g.add_argument("--config", help="YAML config (plain sections or a ROS 2 parameter file) "
                       "(default: none, the built-in values)")
        g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="override a config value, e.g. --set train.epochs=10 (repeatable)")
        g.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's own choice)")
        g.add_argument("--no-progress", action="store_true", help="no progress bars")

    # -- cache ---------------------------------------------------------------------------------
    c = sub.add_parser("cache", help="simulate drives / read recordings and preprocess them into a cache folder",
                       formatter_class=HelpFormatter)
    common(c)
    c.add_argument("--out", required=True, help="cache folder (drives already there are kept)")
    g = c.add_argument_group("simulated drives")
    g.add_argument("--split", choices=("train", "val", "test"), default="train",
                   help="seed range: train from 10000, val from 80000, test from 90000 (disjoint)")
    g.add_argument("--drives", type=int, default=0, help="number of drives (seeds base..base+drives-1)")
    g.add_argument("--seeds", help="explicit seeds instead: 'A:B' or 'S1,S2' (checked against the other splits)")
    g.add_argument("--scenes", default=",".join(SCENES), help="scene types, cycled over the seeds")
    g.add_argument("--frames", type=int, default=25, help="frames per drive (10 Hz)")
    g.add_argument("--randomize-sensor", choices=("auto", "yes", "no"), default="auto",
                   help="random LiDAR model/angles/noise/dropout/mounting per drive (auto: train yes, val/test no)")
    g.add_argument("--cache-points", type=int, default=4096, help="points kept per frame (FPS of the voxel grid)")
    g.add_argument("--sensors", default="",
                   help="sensor presets drawn per drive (deepbbs-sim --lidar names, 'random' = the randomised "
                        "road sensors), e.g. 'random,os1_64,avia,mid360' (default: the randomised road sensors)")
    g.add_argument("--mounts", default="",
                   help="mounts drawn per drive: car, wheeled, legged, handheld (default: car)")
    g.add_argument("--min-span", type=float, default=0.0, metavar="M",
                   help="m; a drive's frames are every s-th sweep, s (at most 10) the smallest whose frames travel "
                        "this far, so slow mounts have pairs as far apart as cars (e.g. 2 x train.max_dist); "
                        "0 = consecutive sweeps; the randomised road drives always are")
    g.add_argument("--sweeps", choices=("mixed", "compensated"), default="mixed",
                   help="mixed: each drive's seed draws compensated (half), raw (30 %%) or ideal sweeps; compensated: "
                        "every sweep compensated to its stamp, so its label (the pose at the stamp) is right")
    g = c.add_argument_group("a user's recording")
    g.add_argument("--source", action="append", default=[], help="bag / mcap / Apollo or KITTI folder (repeatable)")
    g.add_argument("--topic", help="PointCloud2 topic (needed when there are several)")
    g.add_argument("--gt-topic", help="ground-truth pose topic")
    g.add_argument("--every", type=int, default=1, help="keep every k-th scan")
    g.add_argument("--max-frames", type=int, default=0, help="at most this many scans (0 = all)")

    # -- fit -----------------------------------------------------------------------------------
    f = sub.add_parser("fit", help="train (or resume) a model", formatter_class=HelpFormatter)
    common(f)
    g = f.add_argument_group("data")
    g.add_argument("--cache", action="append", default=[], help="training cache folder(s) (repeatable)")
    g.add_argument("--val-cache", action="append", default=[], help="held-out cache folder(s) for validation")
    g = f.add_argument_group("run")
    g.add_argument("--run", "--run-dir", dest="run", required=True,
                   help="run folder: logs, checkpoints, curves (write --run-dir under torchrun, whose own parser "
                   "takes --run for its --run-path)")
    g.add_argument("--resume", nargs="?", const="", default=None, metavar="STATE",
                   help="continue from the run folder's state_latest.pt (or STATE); data and config are "
                        "taken from the run's saved command unless given again")
    g.add_argument("--init", help="start from these weights (fine-tuning; 'shipped' = the packaged model); "
                                  "their model config is used (default: a random start)")
    g.add_argument("--device", help=f"auto | cpu | cuda | cuda:N (default: {config_default('registration.device')})")
    g.add_argument("--max-steps", type=int, help="stop after this many more steps (default: no limit)")
    g.add_argument("--until-epoch", type=int,
                   help="stop when this many epochs are done (a phase of a schedule) (default: train.epochs)")
    g.add_argument("--time-budget-min", type=float,
                   help="stop (after saving) after this many minutes (default: no limit)")

    # -- evaluate -------------------------------------------------------------------------------
    e = sub.add_parser("evaluate", help="accuracy on held-out simulated drives (the model card figures)",
                       formatter_class=HelpFormatter)
    common(e)
    e.add_argument("--weights", default="", help="checkpoint (default: the shipped model)")
    e.add_argument("--device", help=f"auto | cpu | cuda | cuda:N (default: {config_default('registration.device')})")
    e.add_argument("--scenes", default=",".join(SCENES), help="scene types")
    e.add_argument("--rigs", default="", help="sensor:mount:place list instead of --scenes (other sensors, "
                   "mounts and places), e.g. avia:handheld:courtyard,os1_64:wheeled:hall")
    e.add_argument("--drives-per-scene", type=int, default=4, help="held-out drives per scene type")
    e.add_argument("--seed-base", type=int, default=None, help="first seed (default: the test split, 90000)")
    e.add_argument("--frames", type=int, default=60, help="frames per drive")
    e.add_argument("--stride", type=int, default=10, help="a source frame every stride frames (pair protocol)")
    e.add_argument("--yaw-deg", type=float, default=45.0, help="extra random yaw of the second pass (0 = skip)")
    e.add_argument("--raw-sweeps", action="store_true",
                   help="register the raw motion-distorted sweeps (default: sweeps compensated to their stamps)")
    e.add_argument("--methods", default="deepbbs++,deepbbs,refine-only,gicp,gicp-gt",
                   help="deepbbs++ (full), deepbbs (no refinement), refine-only (no network), gicp (small_gicp "
                   "from identity), gicp-gt (small_gicp from the ground truth: the pair's conditioning floor)")
    e.add_argument("--out", help="write all figures and per-pair errors to this JSON file")
    e.add_argument("--markdown", help="also write the summary tables as Markdown (for MODEL.md) to this file")

    # -- adapt ----------------------------------------------------------------------------------
    a = sub.add_parser("adapt", help="fine-tune the model on an unlabeled recording of your sensor (pseudo-labels "
                       "from the answers the verdict accepts) and report before / after on scans held back",
                       formatter_class=HelpFormatter)
    common(a)
    a.add_argument("recording", help="bag / mcap / Apollo, KITTI or scan folder (anything deepbbs-replay reads)")
    a.add_argument("--out", required=True, help="folder: labels, checkpoints, log, model_adapted.pt, report")
    a.add_argument("--resume", action="store_true", help="continue the adaptation in --out (labels and training)")
    g = a.add_argument_group("recording")
    g.add_argument("--topic", help="PointCloud2 topic (needed when there are several)")
    g.add_argument("--every", type=int, default=1, help="keep every k-th scan")
    g.add_argument("--max-frames", type=int, default=0, help="at most this many scans (0 = all)")
    g.add_argument("--held-back", type=float, default=0.3, help="share of the scans, at the end, held back")
    g.add_argument("--gap", type=int, default=5, help="scans dropped between the adaptation and held-back parts")
    g = a.add_argument_group("pseudo-labels")
    g.add_argument("--strides", default="1,2,4", help="pairs (i, i + s) for these strides s")
    g.add_argument("--cycle-rot-deg", type=float, default=1.0, help="triplets agree within this rotation")
    g.add_argument("--cycle-trans", type=float, default=0.3, help="m; and this translation")
    g = a.add_argument_group("fine-tuning (the loss and augmentation the weights were trained with; --set train.* "
                             "changes them)")
    g.add_argument("--steps", type=int, default=200, help="optimiser steps")
    g.add_argument("--lr", type=float, default=1e-4, help="learning rate of the fine-tuning (replaces train.lr)")
    g.add_argument("--time-budget-min", type=float, help="stop (after saving) after this many minutes")
    g.add_argument("--device", help=f"auto | cpu | cuda | cuda:N (default: {config_default('registration.device')})")
    g = a.add_argument_group("report (uses the recording's poses when it has them, never for training)")
    g.add_argument("--eval-stride", type=int, default=1, help="a held-back source every this many scans")
    g.add_argument("--eval-max-dist", type=float, default=5.0, help="m; target: the last scan within this distance")
    g.add_argument("--perturb-yaw", type=float, default=45.0, help="deg; random start yaw of the perturbed starts")
    g.add_argument("--perturb-trans", type=float, default=2.0, help="m; random start shift of the perturbed starts")
    g.add_argument("--trials", type=int, default=2, help="perturbed starts per pair")
    g.add_argument("--no-report", action="store_true", help="skip the before / after registrations")

    # -- report ---------------------------------------------------------------------------------
    r = sub.add_parser("report", help="Markdown summary of a run: speed, validation history, best checkpoint",
                       formatter_class=HelpFormatter)
    r.add_argument("--run", required=True, help="run folder")
    return p


def _cmd_cache(args) -> int:
    from deepbbs_ros.train import cache as C
    from deepbbs_ros.train import sim_cache as S

    cfg = _config(args)
    out = Path(args.out)
    written = []
    if args.source:
        for src in args.source:
            written.append(C.cache_recording(src, out, cfg.preprocess, args.cache_points, topic=args.topic,
                                             gt_topic=args.gt_topic, every=args.every, max_frames=args.max_frames,
                                             progress=not args.no_progress))
    if args.drives or args.seeds:
        base = {"train": C.TRAIN_SEED_BASE, "val": C.VAL_SEED_BASE, "test": C.TEST_SEED_BASE}[args.split]
        seeds = _seeds(args.seeds) if args.seeds else list(range(base, base + args.drives))
        others = [range(b, b + 10_000) for s, b in (("train", C.TRAIN_SEED_BASE), ("val", C.VAL_SEED_BASE),
                                                    ("test", C.TEST_SEED_BASE)) if s != args.split]
        C.check_disjoint_seeds(seeds, *others)
        scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
        randomize = args.randomize_sensor == "yes" or (args.randomize_sensor == "auto" and args.split == "train")
        sensors = [s.strip() for s in args.sensors.split(",") if s.strip()] or None
        mounts = [m.strip() for m in args.mounts.split(",") if m.strip()] or None
        specs = S.sim_drive_specs(scenes, seeds, args.frames, sensors=sensors, mounts=mounts,
                                  min_span=args.min_span, sweeps=args.sweeps)
        written += list(S.build_sim_cache(out, specs, cfg.preprocess, args.cache_points,
                                          randomize_sensor=randomize, progress=not args.no_progress))
        manifest = out / "manifest.json"
        info = json.loads(manifest.read_text()) if manifest.exists() else {}
        info[f"{args.split}:{seeds[0]}..{seeds[-1]}"] = {
            "scenes": scenes, "seeds": [seeds[0], seeds[-1]], "frames": args.frames,
            "randomize_sensor": randomize, "cache_points": args.cache_points,
            **({"sensors": sensors, "mounts": mounts} if sensors or mounts else {}),
            **({"min_span": args.min_span} if args.min_span > 0 else {}),
            **({"sweeps": args.sweeps} if args.sweeps != "mixed" else {}),
            "command": "deepbbs-train " + shlex.join(sys.argv[1:]) if sys.argv else ""}
        manifest.write_text(json.dumps(info, indent=2))
    if not args.source and not (args.drives or args.seeds):
        raise ConfigError("cache: give --drives N / --seeds, or --source PATH")
    n_frames = 0
    for path in written:
        from deepbbs_ros.train.cache import load_drive

        n_frames += len(load_drive(path))
    print(f"deepbbs-train cache: {len(written)} new drive(s), {n_frames} frames in {out}")
    return 0


def _cmd_fit(args) -> int:
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
    from deepbbs_ros.train.run_state import STATE_FILE
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
        from deepbbs_ros.train.run_state import STATE_FILE

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


def _cmd_evaluate(args) -> int:
    from deepbbs_ros.train.evaluate import evaluate, print_report

    cfg = _config(args)
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    report = evaluate(cfg, weights=args.weights, device=args.device, scenes=scenes,
                      drives_per_scene=args.drives_per_scene, seed_base=args.seed_base, frames=args.frames,
                      stride=args.stride, yaw_deg=args.yaw_deg, methods=methods, progress=not args.no_progress,
                      raw_sweeps=args.raw_sweeps, rigs=[r.strip() for r in args.rigs.split(",") if r.strip()])
    print_report(report)
    if args.markdown:
        from deepbbs_ros.train.evaluate import markdown_report

        Path(args.markdown).write_text(markdown_report(report))
        print(f"wrote {args.markdown}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.out}")
    return 0


def _cmd_adapt(args) -> int:
    from deepbbs_ros.cli.adapt import run_adapt

    return run_adapt(args, _config(args))


def _sigterm(signum, frame):
    raise KeyboardInterrupt


def _cmd_report(args) -> int:
    from deepbbs_ros.train.run_log import run_report

    print(run_report(args.run))
    return 0


@cli_entry("deepbbs-train")
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    _set_threads(getattr(args, "threads", 0))
    # SIGTERM (kill PID) behaves like Ctrl-C: the loop saves its state before exiting
    signal.signal(signal.SIGTERM, _sigterm)
    commands = {"cache": _cmd_cache, "fit": _cmd_fit, "evaluate": _cmd_evaluate, "report": _cmd_report,
                "adapt": _cmd_adapt}
    return commands[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
