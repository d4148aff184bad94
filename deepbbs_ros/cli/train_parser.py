"""deepbbs-train's arguments: the parser (a subcommand each, argument groups), its usage text, and the config the
``--config`` / ``--set`` arguments give."""

from __future__ import annotations

import argparse

from deepbbs_ros.cli.common import HelpFormatter, RawHelpFormatter, config_default
from deepbbs_ros.errors import ConfigError

#: the description (first paragraph) and the examples of ``deepbbs-train --help``
USAGE = """deepbbs-train: build a training cache, train DeepBBS++ (resumable), evaluate weights.

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


def build_parser() -> argparse.ArgumentParser:
    from deepbbs_ros.sim import SCENES

    head, usage = USAGE.split("\n\n", 1)
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
