#!/usr/bin/env python3
"""``registration.good_start_degenerate`` end to end: what the good start answers with the rule on and off.

On verdict.py's simulated pairs (the same draws: :func:`verdict.sim_parts`, calibrate_verdict.py's near and far
starts: the truth moved 0-3 deg / 0-0.5 m, 10-45 deg / 1-4 m and 5-30 deg / 0.5-3 m), the good start alone
(core/good_start.py ``attempt``) finds the starts where the rule fires; on each of those, and on a share of the
others (``--control``: the same code runs either way, a check of the harness), ``register(..., good_start=True)``
runs with the rule on and off (two registrations, the same prepared clouds). Per family (``dense``, ``sparse``,
``solid``, ``low_overlap``, ``turned``) and setting: right (1 deg / 0.3 m) and valid, wrong (beyond 2 deg / 0.5 m)
and valid (a wrong answer accepted), in between and valid, right not valid, not right nor valid; the wall time (ms,
medians) and the ratio on / off per start (median); ``lost``: the starts whose answer is right and valid off and not
on. ``starts``: every start's good start alone: taken, fired, left to the full pipeline; per row ``beyond``: how GICP
from the start went beyond the good start's limits (``registration.good_start_max_*``, "" within), ``moved``: each
answer's distance from the start (deg, m). ::

    python scripts/benchmarks/good_start_degenerate.py --seed 39 --out results/degenerate39   # and 40, 41, 42, 43
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import _common  # noqa: E402
import numpy as np  # noqa: E402
import verdict  # noqa: E402

from deepbbs_ros.metrics import pair_errors  # noqa: E402

CLASSES = ("right_valid", "wrong_valid", "between_valid", "right_not_valid", "not_right_not_valid")


def outcome(res, T_gt: np.ndarray) -> tuple[str, float, float]:
    """(the class of a result against the truth (:data:`CLASSES`), its error deg, m)."""
    import calibrate_verdict as cv

    y, r, t = cv.label(res.T_target_source, T_gt)
    if res.valid:
        return ("right_valid" if y == 1 else "wrong_valid" if y == 0 else "between_valid"), r, t
    return ("right_not_valid" if y == 1 else "not_right_not_valid"), r, t


def family(rig: int) -> str:
    """The family of a simulated rig index, the low-overlap and turned rigs apart (as verdict.py judges them)."""
    import calibrate_verdict as cv

    return "turned" if rig >= len(cv.RIGS) + len(cv.LOW_RIGS) else "low_overlap" if rig >= len(cv.RIGS) else \
        verdict.family(rig)


class Runs:
    """The callback of calibrate_verdict.py ``collect``'s ``starts``: each start judged (see the module)."""

    def __init__(self, config, control: float, seed: int):
        from deepbbs_ros.core.registration import DeepBBSRegistration

        on = dataclasses.replace(config, registration=dataclasses.replace(config.registration,
                                                                          good_start_degenerate=True))
        off = dataclasses.replace(config, registration=dataclasses.replace(on.registration,
                                                                           good_start_degenerate=False))
        self.alone, self.on, self.off = (DeepBBSRegistration(c) for c in (on, on, off))
        self.control, self.rng, self.rows, self.starts = control, np.random.default_rng(seed), [], {}

    def __call__(self, kind: str, src, tgt, T0: np.ndarray, T_gt: np.ndarray, rig: int) -> None:
        from deepbbs_ros.core.good_start import attempt
        from deepbbs_ros.core.network_output import Clock

        first = attempt(self.alone, src, tgt, T0, True, Clock(self.alone.device))
        fired = first.result is not None and first.reason.startswith("not valid: degenerate")
        what = "fired" if fired else "taken" if first.result is not None else "pipeline"
        fam = family(rig)
        self.starts.setdefault(fam, {"taken": 0, "fired": 0, "pipeline": 0})[what] += 1
        if not fired and self.rng.random() >= self.control:
            return
        row = {"family": fam, "kind": kind, "fired": fired, "beyond": self.beyond(src, tgt, T0)}
        for name, reg in (("off", self.off), ("on", self.on)):  # the search first: it builds the lazy samples
            t0 = time.perf_counter()
            res = reg.register(src, tgt, T_init=T0, preprocessed=True, good_start=True)
            ms = (time.perf_counter() - t0) * 1e3
            cls, r, t = outcome(res, T_gt)
            moved = [round(float(v), 2) for v in pair_errors(res.T_target_source, T0)]  # from the start
            row[name] = {"class": cls, "deg": round(r, 2), "m": round(t, 2), "moved": moved, "ms": round(ms, 1),
                         "path": res.path,
                         "probability": round(float(res.probability), 3), "why": res.good_start[:80]}
        self.rows.append(row)
        print(fam, kind, "fired" if fired else "control", {k: row[k]["class"] for k in ("off", "on")},
              row["off"]["ms"], "->", row["on"]["ms"], "ms", flush=True)

    def beyond(self, src, tgt, T0: np.ndarray) -> str:
        """How GICP from the start went beyond the good start's limits (core/good_start.py ``_beyond``; "" within)."""
        from deepbbs_ros.core import good_start

        rc = self.alone.config.registration
        return good_start._beyond(good_start.from_start(src.polish_cloud, tgt.polish_cloud, T0, rc), rc)


def tally(rows: list[dict], fired: bool) -> dict:
    """Per family and setting: the classes' counts, the wall time's median (ms) and the ratio on / off; ``lost``."""
    out = {}
    for fam in sorted({r["family"] for r in rows if r["fired"] == fired}):
        rs = [r for r in rows if r["fired"] == fired and r["family"] == fam]
        out[fam] = {"starts": len(rs), **{name: {**{c: sum(r[name]["class"] == c for r in rs) for c in CLASSES},
                                                 "ms_p50": round(float(np.median([r[name]["ms"] for r in rs])), 1)}
                                          for name in ("off", "on")},
                    "ratio_on_off_p50": round(float(np.median([r["on"]["ms"] / r["off"]["ms"] for r in rs])), 4),
                    "lost": [r for r in rs if r["off"]["class"] == "right_valid" != r["on"]["class"]],
                    "differ": sum(r["off"]["class"] != r["on"]["class"] for r in rs)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=39, help="simulation seed (verdict.py's; default 39)")
    ap.add_argument("--sim-pairs", type=int, default=4, help="simulated pairs per rig (default 4)")
    ap.add_argument("--sim-low-pairs", type=int, default=6, help="low-overlap pairs per rig (default 6)")
    ap.add_argument("--sim-turned-pairs", type=int, default=4, help="turned pairs per rig (default 4)")
    ap.add_argument("--control", type=float, default=0.02,
                    help="share of the starts where the rule does not fire also run on and off (default 0.02)")
    ap.add_argument("--config", type=Path, help="config YAML of the registration (default: the defaults)")
    ap.add_argument("--out", type=Path, default=Path("results/benchmarks"))
    args = ap.parse_args(argv)

    from deepbbs_ros.config import Config, load_config

    config = load_config(args.config) if args.config else Config()
    runs = Runs(config, args.control, args.seed)
    verdict.sim_parts(args.sim_pairs, args.seed, args.sim_low_pairs, args.sim_turned_pairs, config=config,
                      starts=runs)
    figures = {"seed": args.seed, "starts": runs.starts, "fired": tally(runs.rows, True),
               "control": tally(runs.rows, False), "rows": runs.rows}
    for k in ("starts", "fired", "control"):
        print(k, figures[k], flush=True)
    _common.write_json(args.out, f"good_start_degenerate_{args.seed}.json", figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
