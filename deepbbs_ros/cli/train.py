"""deepbbs-train: build a training cache, train DeepBBS++ (resumable), evaluate weights, adapt to a recording.

The arguments and the examples of ``--help`` are cli/train_parser.py's, ``fit`` cli/train_fit.py's, ``adapt``
cli/adapt.py's; this module runs the command.
"""

from __future__ import annotations

import json
import shlex
import signal
import sys
from pathlib import Path

from deepbbs_ros.cli.adapt import run_adapt
from deepbbs_ros.cli.common import cli_entry
from deepbbs_ros.cli.train_fit import run_fit
from deepbbs_ros.cli.train_parser import _config, _seeds, build_parser
from deepbbs_ros.errors import ConfigError


def _set_threads(n: int) -> None:
    if n > 0:
        import torch

        torch.set_num_threads(n)


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


def _cmd_evaluate(args) -> int:
    from deepbbs_ros.train.eval_report import print_report
    from deepbbs_ros.train.evaluate import evaluate

    cfg = _config(args)
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    report = evaluate(cfg, weights=args.weights, device=args.device, scenes=scenes,
                      drives_per_scene=args.drives_per_scene, seed_base=args.seed_base, frames=args.frames,
                      stride=args.stride, yaw_deg=args.yaw_deg, methods=methods, progress=not args.no_progress,
                      raw_sweeps=args.raw_sweeps, rigs=[r.strip() for r in args.rigs.split(",") if r.strip()])
    print_report(report)
    if args.markdown:
        from deepbbs_ros.train.eval_report import markdown_report

        Path(args.markdown).write_text(markdown_report(report))
        print(f"wrote {args.markdown}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=2))
        print(f"wrote {args.out}")
    return 0


def _cmd_adapt(args) -> int:
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
    commands = {"cache": _cmd_cache, "fit": run_fit, "evaluate": _cmd_evaluate, "report": _cmd_report,
                "adapt": _cmd_adapt}
    return commands[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
