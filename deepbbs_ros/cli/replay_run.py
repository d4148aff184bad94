"""One deepbbs-replay run of a recording: the loop with its progress bar, then every output (metrics.json, CSV,
trajectories, plots, the results bag, the table), also after Ctrl-C or a reader fault."""

from __future__ import annotations

import sys
from pathlib import Path

from deepbbs_ros.cli.replay_hints import PositionLog, pair_count_hint
from deepbbs_ros.cli.replay_parser import PROG


def run_replay(args, cfg, source, methods, results=None) -> int:
    """Run the loop with a progress bar, then write every output (also after Ctrl-C / a reader fault)."""
    from deepbbs_ros.errors import DatasetError
    from deepbbs_ros.replay import report

    run = report.make_run_dir(args.out)
    cfg.to_yaml(run / "config_used.yaml")
    res, logged = _replay_loop(args, cfg, source, methods, results)
    interrupted = any("Ctrl-C" in e for e in res.errors)
    if source.errors:
        res.complete = False
        at = list(getattr(source, "fault_at", []))
        at += [res.frames_read] * (len(source.errors) - len(at))
        res.errors.extend(f"recording fault after {n} frames: {e}" for n, e in zip(at, source.errors))

    if res.frames_read == 0 and source.errors:
        raise DatasetError(f"no scan could be read: {source.errors[0]}")
    if not interrupted and hasattr(source, "check_not_empty"):
        source.check_not_empty()  # --start / --end outside the recording: one line
    from deepbbs_ros.replay.checks import frame_offset, nothing_answered

    none = None if interrupted else nothing_answered(args.mode, res)
    if none:  # every pair, frame or scan failed: the run says so (results so far written all the same)
        res.complete = False
        res.errors.insert(0, none)

    if args.mode == "pairs":
        mm = report.pair_metrics(res, cfg)
    elif args.mode == "localization":
        mm = report.localization_metrics(res, cfg)
    else:
        mm = report.odometry_metrics(res)
    warnings = list(getattr(source, "warnings", [])) + list(getattr(res, "warnings", []))
    if args.mode == "pairs" and res.complete and not (args.max_pairs and res.pairs >= args.max_pairs):
        hint = pair_count_hint(logged.positions, cfg.eval, res.pairs)
        if hint:
            warnings.append(hint)
    extra = {"weights": str(args.weights or cfg.registration.weights or "shipped default"),
             "device": args.device or cfg.registration.device}
    if args.mode == "localization":
        from deepbbs_ros.datasets.maps import trajectory_path

        tum = trajectory_path(args.map)
        extra["map"] = {"path": str(args.map), "points": res.map_points,
                        "trajectory": str(tum) if tum.is_file() else None}
        offset = frame_offset(res.records, cfg.eval.success_rot_deg, cfg.eval.success_trans)
        if offset:  # every pose off the truth by one rigid motion: the map and the truth in different frames
            extra["frame_offset"] = offset
            warnings.append(offset["message"])

    def write_json():
        report.write_metrics_json(run / "metrics.json", source=str(args.source), mode=args.mode, res=res, config=cfg,
                                  method_metrics=mm, extra={**extra, "warnings": warnings})

    write_json()
    if args.mode == "pairs":
        report.write_pairs_csv(run / "pairs.csv", res)
    elif args.mode == "localization":
        report.write_localization_csv(run / "scans.csv", res)
        report.write_localization_trajectories(run, res)
    else:
        report.write_odometry_csv(run / "frames.csv", res)
        report.write_trajectories(run, res)
    plots = []
    failed_outputs = []
    if not args.no_plots:
        from deepbbs_ros.replay import plots as P

        try:
            if args.mode == "pairs":
                plots = P.plot_pairs(run, res, cfg.eval.success_rot_deg, cfg.eval.success_trans)
            elif args.mode == "localization":
                plots = P.plot_localization(run, res, cfg.eval.success_rot_deg, cfg.eval.success_trans)
            else:
                plots = P.plot_odometry(run, res)
        except Exception as err:  # noqa: BLE001 - a plot must not cost the results already computed
            failed_outputs.append(f"plots not written ({type(err).__name__}: {err})")
    if not args.no_bag:
        try:
            report.write_results_bag(run / "results_bag", res)
        except Exception as err:  # noqa: BLE001 - nor may the results bag
            failed_outputs.append(f"results bag not written ({type(err).__name__}: {err})")
    if failed_outputs:
        warnings.extend(failed_outputs)
        write_json()
    for w in warnings if res.complete else ():  # an incomplete run ends in one error line; all are in metrics.json
        print(f"{PROG}: warning: {w}", file=sys.stderr)

    title = f"deepbbs-replay {args.mode}: {Path(args.source).name}" + ("" if res.complete else " (INCOMPLETE)")
    report.print_table(args.mode, mm, title=title, has_ground_truth=source.has_ground_truth)
    print(f"results: {run}  (latest: {Path(args.out) / 'latest'})")
    if plots:
        print("plots:   " + ", ".join(p.name for p in plots))
    if interrupted:
        print(f"{PROG}: interrupted; results so far written to {run} (marked incomplete)", file=sys.stderr)
        return 130
    if not res.complete:
        more = f"; {len(res.errors) - 1} more in metrics.json" if len(res.errors) > 1 else ""
        print(f"{PROG}: error: {res.errors[0]}{more} (results so far written to {run}, marked incomplete)",
              file=sys.stderr)
        return 1
    return 0


def _replay_loop(args, cfg, source, methods, results):
    """The protocol of ``args.mode`` over ``source`` with a progress bar (frames): (its results, the
    :class:`PositionLog` of pairs mode or None). Ctrl-C ends it with the results so far, marked incomplete."""
    from tqdm import tqdm

    from deepbbs_ros.replay.loop import mark_interrupted
    from deepbbs_ros.replay.runner import OdometryResults, PairResults, run_localization, run_odometry, run_pairs

    total = len(source)
    if args.max_frames and args.mode != "pairs":
        total = min(total, args.max_frames * cfg.eval.odom_stride)
    bar = tqdm(total=total, unit="frames", desc=f"replay {args.mode}", disable=args.quiet, dynamic_ncols=True)
    logged = None
    if args.mode == "pairs":
        res = PairResults(list(methods))
        logged = PositionLog(source)

        def progress(n):
            bar.update(n)
            bar.set_postfix(pairs=res.pairs, refresh=False)

        def loop():
            run_pairs(logged, methods, cfg, max_pairs=args.max_pairs, progress=progress, results=res)
    elif args.mode == "localization":
        res = results

        def loop():
            run_localization(source, methods["deepbbs++"], cfg, max_frames=args.max_frames, progress=bar.update,
                             results=res)
    else:
        res = OdometryResults(list(methods))

        def loop():
            run_odometry(source, methods, cfg, max_frames=args.max_frames, progress=bar.update, results=res)
    try:
        loop()
    except KeyboardInterrupt:  # outside the loop proper (e.g. while closing the reader)
        mark_interrupted(res)
    bar.close()
    return res, logged
