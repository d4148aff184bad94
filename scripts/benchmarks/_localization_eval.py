"""The localization benchmark's protocol (scripts/benchmarks/localization.py): every method on the queries of one
map, the boot protocol, the map-size scaling and the scans from outside the map."""

from __future__ import annotations

import numpy as np
from _localization_baselines import FpfhRansacSolver, KissMatcherSolver
from _localization_data import KINDS, MapData, Query
from _localization_methods import METHODS, ExactTimed, Isolated, MapLocalizerMethod
from _localization_scores import judge, reliability, summarize


def boot_rows(method, rows: list[dict], queries: list[Query], log=print, name: str = "") -> list[dict]:
    """The boot protocol (the node's case: it takes the next scans while it is not placed yet): a query that got no
    pose goes on with its drive's ``follow`` scans, each searched from no guess once it has arrived and the search
    before it has ended, until one is placed; -> per query the first pose's row, ``time_s`` from the query scan's
    arrival to that pose (the searches and the waits), ``scans`` how many were searched. A first answer that was
    placed or wrong stands (the node would publish it)."""
    out = []
    for row, q in zip(rows, queries):
        b = dict(row, scans=1)
        t = row["time_s"]
        if row["outcome"] == "none":
            for n, (dt, pts, T) in enumerate(q.follow, 2):
                ans = method(pts)
                start = max(dt, t)
                b = dict(judge(ans, Query(pts, T, q.place, q.kind, q.s, q.repetitive)), query=row["query"], scans=n)
                t = start + ans.time_s
                b["time_s"] = t
                if b["outcome"] != "none":
                    break
            log(f"  {name} boot [{q.kind}]: {b['outcome']} after {b['scans']} scan(s), {t:.2f} s")
        out.append(b)
    return out


def baseline_subset(n: int, every: int) -> list[int]:
    """Every ``every``-th of ``n`` queries, stepping one further each round of the query kinds, so that the subset
    holds every kind (plain multiples of 3 would all be one kind of 3)."""
    every = max(1, int(every))
    return [i for i in range(n) if (i + i // len(KINDS)) % every == 0]


def _prior(q: Query, i: int, radius: float) -> tuple[np.ndarray, float]:
    """A coarse position prior for query ``i``: within radius / 4 of the truth (fixed seed), with ``radius``."""
    rng = np.random.default_rng([i, 77])
    a, r = rng.uniform(0, 2 * np.pi), radius / 4 * np.sqrt(rng.uniform())
    return q.T_map_scan[:2, 3] + r * np.array([np.cos(a), np.sin(a)]), float(radius)


def make_method(name: str, points: np.ndarray, trajectory: np.ndarray | None, args, config=None, factories=None):
    """The method ``name`` prepared for this map, or a string saying why it cannot run here. ``factories``:
    optional name -> callable(points, trajectory) replacing the built-in methods (tests)."""
    try:
        if factories and name in factories:
            return factories[name](points, trajectory)
        exact = not getattr(args, "inexact", False)
        if name == "maplocalizer":
            return MapLocalizerMethod(points, None if args.grid_places else trajectory, config, exact=exact)
        kind = ExactTimed if exact else Isolated
        if name == "kiss-matcher+gicp":
            m = kind(name, KissMatcherSolver, points, args.baseline_timeout, config=config, voxel=args.km_voxel)
        elif name == "fpfh-ransac+gicp":
            m = kind(name, FpfhRansacSolver, points, args.baseline_timeout, config=config, voxel=args.fpfh_voxel)
        else:
            raise SystemExit(f"unknown method {name!r} (known: {', '.join(METHODS)})")
        m.start()  # build the map's side now (its own time, not a query's)
        return m
    except (ImportError, OSError) as err:
        return f"skipped: {err}"


def evaluate_map(data: MapData, methods: list[str], args, config=None, log=print, factories=None) -> dict:
    """Every method on the queries of one map (baselines on every ``--baseline-every``-th), then the map-size
    scaling of MapLocalizer: the queries within the shortest prefix against every prefix. The core function
    of the benchmark (tests/test_bench_localization.py runs it on a tiny map)."""
    fig: dict = {"map_points": len(data.points), "map_keyframes": len(data.trajectory), "map_length_m": data.length_m,
                 "queries": len(data.queries), "methods": {}, "rows": {}}
    for name in methods:
        idx = list(range(len(data.queries))) if name == "maplocalizer" else \
            baseline_subset(len(data.queries), args.baseline_every)
        m = make_method(name, data.points, data.trajectory, args, config, factories)
        if isinstance(m, str):
            fig["methods"][name] = {"note": m}
            log(f"  {name}: {m}")
            continue
        rows = []
        for n, i in enumerate(idx):
            q = data.queries[i]
            if name != "maplocalizer" and getattr(args, "baseline_prior", 0.0) > 0:
                row = judge(m(q.points, prior=_prior(q, i, args.baseline_prior)), q)
            else:
                row = judge(m(q.points), q)
            row["query"] = i
            rows.append(row)
            err = "" if row["rot_err_deg"] is None else f" {row['rot_err_deg']:.2f} deg {row['trans_err_m']:.2f} m"
            cpu = f" (CPU {row['cpu_s']:.2f} s)" if np.isfinite(row["cpu_s"]) else ""
            log(f"  {data.name} {name} {n + 1}/{len(idx)} [{q.kind}{' ' + q.repetitive if q.repetitive else ''}]: "
                f"{row['outcome']}{err} {row['time_s']:.2f} s{cpu} {row['reason'][:80]}")
        boot = boot_rows(m, rows, [data.queries[i] for i in idx], log, data.name) if name == "maplocalizer" else []
        if hasattr(m, "close"):
            m.close()
        s = summarize(rows)
        if name == "maplocalizer":
            s["reliability"] = reliability(rows)
            log(f"  {data.name} map verdict reliability (answer's probability: queries, share right): "
                + ", ".join(f"{k} {v[0]} {v[1]:.2f}" for k, v in s["reliability"].items()))
        if boot:
            s["boot"] = summarize(boot)
            fig.setdefault("boot_rows", {})[name] = boot
        s["build_s"] = m.build_s
        rep = [r for r in rows if r["repetitive"]]
        if rep:
            s["repetitive"] = summarize(rep)
        kinds = sorted({r["kind"] for r in rows})
        if len(kinds) > 1:
            s["by_kind"] = {k: summarize([r for r in rows if r["kind"] == k]) for k in kinds}
        fig["methods"][name] = s
        fig["rows"][name] = rows
    if "maplocalizer" in fig["rows"] and args.baseline_every > 1:  # the baselines' subset, for a like comparison
        sub = set(baseline_subset(len(data.queries), args.baseline_every))
        fig["methods"]["maplocalizer"]["baseline_subset"] = summarize(
            [r for r in fig["rows"]["maplocalizer"] if r["query"] in sub])
    if data.prefixes and args.scaling_queries > 0 and "maplocalizer" in fig["rows"]:
        shortest = min(data.prefixes)
        near = [i for i, q in enumerate(data.queries) if q.s <= shortest - 20.0][:args.scaling_queries]
        scaling = {}
        sizes = [(L, *data.prefixes[L]) for L in sorted(data.prefixes)] + [(int(round(data.length_m)), data.points,
                                                                            data.trajectory)]
        for L, pts, traj in sizes:
            m = make_method("maplocalizer", pts, traj, args, config, factories)
            if isinstance(m, str):
                break
            rows = [judge(m(data.queries[i].points), data.queries[i]) for i in near]
            s = summarize(rows)
            s.update(build_s=m.build_s, map_points=len(pts))
            scaling[str(L)] = s
            log(f"  {data.name} scaling {L} m: {len(pts)} points, build {m.build_s:.1f} s, "
                f"p50 {s.get('time_s_p50', float('nan')):.2f} s, placed {s.get('placed_share', 0):.2f}")
        fig["scaling"] = {"queries": near, "by_map_length_m": scaling}
    return fig


def evaluate_outside(data: MapData, outside: list[Query], args, config=None, log=print) -> dict:
    """MapLocalizer on scans from places that are not in the map (``outside``: other maps' queries): the right answer
    is no pose. -> {"queries", "none_share", "wrong_count", "time_s_p50", "time_s_p95", "time_s_max"} (the time to
    the "no pose")."""
    m = make_method("maplocalizer", data.points, data.trajectory, args, config)
    if isinstance(m, str):
        return {"note": m}
    times, cpus, wrong, probs = [], [], 0, []
    for n, q in enumerate(outside):
        ans = m(q.points)
        probs.append(ans.probability)
        times.append(ans.time_s)
        cpus.append(ans.cpu_s)
        wrong += bool(ans.valid)
        log(f"  {data.name} outside {n + 1}/{len(outside)} [{q.place}]: {'WRONG' if ans.valid else 'none'} "
            f"{ans.time_s:.2f} s (CPU {ans.cpu_s:.2f} s) {ans.reason[:70]}")
    t, c = np.array(times), np.array(cpus)
    return {"queries": len(outside), "none_share": 1.0 - wrong / max(len(outside), 1), "wrong_count": wrong,
            "time_s_p50": float(np.percentile(t, 50)), "time_s_p95": float(np.percentile(t, 95)),
            "cpu_s_p50": float(np.nanpercentile(c, 50)), "cpu_s_p95": float(np.nanpercentile(c, 95)),
            "time_s_max": float(t.max()), "probability_max": float(np.nanmax(probs)) if np.any(np.isfinite(probs))
            else float("nan")}
