"""render_docs.py's section of global localization in a prior map."""

from __future__ import annotations

from pathlib import Path

from _render_format import NOT_RUN, Notes, command, ms, not_run_table, pct, table

# the goals docs/benchmarks.md states for localization
GOAL_LOC_PLACED_PCT, GOAL_LOC_P50_S, GOAL_LOC_P95_S = 99.0, 1.0, 3.0


LOC_LABELS = {"maplocalizer": "DeepBBS++ (MapLocalizer)", "kiss-matcher+gicp": "KISS-Matcher + GICP",
              "fpfh-ransac+gicp": "FPFH + RANSAC + GICP"}
LOC_KINDS = {"same-lane": "same lane", "lane": "another lane", "reverse": "the other way"}


def map_label(name: str) -> str:
    return "real (KITTI and the reference pair, pooled)" if name == "real" else f"simulated {name.replace('_', ' ')}"


def loc_share(c: dict, key: str) -> str:
    return pct(None if c.get(key) is None else 100 * c[key])


def loc_time(c: dict) -> str:
    s50, s95 = c.get("time_s_p50"), c.get("time_s_p95")
    return f"{ms(None if s50 is None else 1e3 * s50)} / {ms(None if s95 is None else 1e3 * s95)}"


def loc_goal(c: dict) -> str:
    if not c or c.get("placed_share") is None:
        return "-"
    missed = [w for ok, w in ((100 * c["placed_share"] >= GOAL_LOC_PLACED_PCT, f"placed < {GOAL_LOC_PLACED_PCT:g} %"),
                              (not c.get("wrong_count"), "wrong poses"),
                              ((c.get("time_s_p50") or 0) <= GOAL_LOC_P50_S, f"p50 > {GOAL_LOC_P50_S:g} s"),
                              ((c.get("time_s_p95") or 0) <= GOAL_LOC_P95_S, f"p95 > {GOAL_LOC_P95_S:g} s"))
              if not ok]
    return "met" if not missed else "missed: " + ", ".join(missed)


def loc_exact_time(c: dict) -> str:
    """MapLocalizer's exact twin (GICP solved on one thread): its time p50 / p95, "-" when it did not run."""
    s50, s95 = c.get("exact_time_s_p50"), c.get("exact_time_s_p95")
    return "-" if s50 is None else f"{ms(1e3 * s50)} / {ms(None if s95 is None else 1e3 * s95)}"


def loc_row(label: str, c: dict | None, notes: Notes, with_goal: bool, exact: bool = False) -> list[str]:
    n = (6 if with_goal else 5) + exact
    if not c:
        return [label] + [NOT_RUN] * n
    if "note" in c:
        return [label] + ["-" + notes.mark(c["note"])] * n
    row = [label, pct(100 * c["placed_share"], c.get("queries")) if c.get("placed_share") is not None else "-",
           str(c.get("wrong_count", "-")), loc_share(c, "none_share"), loc_time(c)]
    if exact:
        row.append(loc_exact_time(c))
    timeouts = c.get("timeout_count")
    row[3] += notes.mark(f"{timeouts} timeout(s) among them") if timeouts else ""
    return row + [loc_goal(c)] if with_goal else row + [ms(1e3 * c["build_s"]) if c.get("build_s") else "-"]


BOOT_INTRO = ("From boot, the node's case: a query that gets no pose goes on with its drive's next scans (one "
              "every {step:g} s, up to {n}), each searched once it has arrived and the search before it has ended; "
              "the first pose published counts, its time from the query scan's arrival:")


def localization(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["map", "placed (queries)", "wrong accepted", "no pose", "first pose p50 / p95 ms", "goal"]
    eheader = [*header[:5], "one-thread GICP p50 / p95 ms", "goal"]  # MapLocalizer's exact twin beside
    bheader = ["map, method", "placed (queries)", "wrong accepted", "no pose", "first pose p50 / p95 ms",
               "map build ms"]
    kheader = ["query drives", "simulated urban", "simulated suburban", "simulated highway", "simulated open road"]
    sheader = ["map", "map length: first pose p50 ms (map points)"]
    fig = (doc or {}).get("figures")
    if fig is None:
        maps = ["simulated urban", "simulated suburban", "simulated highway", "simulated open road", "real (pooled)"]
        return (out + ["DeepBBS++ (MapLocalizer), every query:", ""] + not_run_table(eheader, maps) + [""]
                + [BOOT_INTRO.format(step=1.0, n=2), ""] + not_run_table(header, maps[:4]) + [""]
                + ["Beside the baselines, on the same queries (every third):", ""]
                + not_run_table(bheader, [f"{m}, {v}" for m in maps[:1] for v in LOC_LABELS.values()]) + [""]
                + ["MapLocalizer by kind of query:", ""] + not_run_table(kheader, [*LOC_KINDS.values(),
                                                                                  "repetitive places"]) + [""]
                + ["Time against the map's size:", ""] + not_run_table(sheader, maps[:4]))
    maps, pooled = fig.get("maps") or {}, fig.get("pooled") or {}
    notes = Notes()
    rows = [loc_row(map_label(k), (m.get("methods") or {}).get("maplocalizer"), notes, True, exact=True)
            for k, m in maps.items()]
    ml = pooled.get("maplocalizer") or {}
    if ml.get("sim"):
        rows.append(loc_row("all simulated maps", ml["sim"], notes, True, exact=True))
    if ml.get("all") and "real" in maps:
        rows.append(loc_row("all maps", ml["all"], notes, True, exact=True))
    out += ["DeepBBS++ (MapLocalizer), every query:", ""] + table(eheader, rows) + notes.lines() + [""]
    notes = Notes()
    rows = [loc_row(map_label(k), ((m.get("methods") or {}).get("maplocalizer") or {}).get("boot"), notes, True)
            for k, m in maps.items() if k != "real"]
    if ml.get("sim_boot"):
        rows.append(loc_row("all simulated maps", ml["sim_boot"], notes, True))
    if any(r[1] != NOT_RUN for r in rows):
        step = (fig.get("settings") or {}).get("boot_step", 1.0)
        n = (fig.get("settings") or {}).get("boot_scans", 2)
        out += [BOOT_INTRO.format(step=step, n=n), ""] + table(header, rows)
        out += notes.lines() + [""]
    every = (fig.get("settings") or {}).get("baseline_every")
    nth = {1: "every query", 2: "every second query", 3: "every third query"}.get(every, f"every {every}th query")
    notes = Notes()
    rows = []
    for k, m in maps.items():
        ms_ = m.get("methods") or {}
        for name, label in LOC_LABELS.items():
            c = ms_.get(name)
            if name == "maplocalizer" and c and c.get("baseline_subset"):
                c = {**c["baseline_subset"], "build_s": c.get("build_s")}
            if c is None and name not in ms_:
                continue
            rows.append(loc_row(f"{map_label(k).split(' (')[0]}, {label}", c, notes, False))
    out += [f"Beside the baselines, on the same queries ({nth}; each baseline registers the scan against the "
            "whole map):", ""] + table(bheader, rows) + notes.lines() + [""]
    sims = [k for k in maps if k != "real"]
    kheader = ["query drives", *(map_label(k) for k in sims)]
    rows = []
    for kind, label in LOC_KINDS.items():
        cells = []
        for k in sims:
            c = (((maps[k].get("methods") or {}).get("maplocalizer") or {}).get("by_kind") or {}).get(kind)
            cells.append("-" if not c else f"{pct(100 * c['placed_share'], c['queries'])}, wrong {c['wrong_count']}")
        rows.append([label, *cells])
    cells = []
    for k in sims:
        c = ((maps[k].get("methods") or {}).get("maplocalizer") or {}).get("repetitive")
        cells.append("-" if not c else f"{pct(100 * c['placed_share'], c['queries'])}, wrong {c['wrong_count']}")
    rows.append(["repetitive places (long straight stretches)", *cells])
    out += ["MapLocalizer by kind of query (placed, and wrong poses accepted):", ""] + table(kheader, rows) + [""]
    lengths = sorted({int(L) for k in sims for L in ((maps[k].get("scaling") or {}).get("by_map_length_m") or {})})
    if lengths:
        cols = sorted({round(L, -1) for L in lengths})
        sheader = ["map", *(f"{c} m" for c in cols)]
        rows = []
        for k in sims:
            by = (maps[k].get("scaling") or {}).get("by_map_length_m") or {}
            at = {round(int(L), -1): c for L, c in by.items()}
            rows.append([map_label(k), *("-" if at.get(c) is None else
                                         f"{ms(1e3 * at[c]['time_s_p50'])} ({at[c]['map_points']}), placed "
                                         f"{round(at[c]['placed_share'] * at[c]['queries'])} / {at[c]['queries']}, "
                                         f"wrong {at[c].get('wrong_count', 0)}" for c in cols)])
        n = len(((maps[sims[0]].get("scaling") or {}).get("queries")) or [])
        out += [f"Time against the map's size: the first {n} queries of each map against maps of the first metres "
                "of its drive (first pose p50 ms, the map's points in brackets; queries placed and wrong poses "
                "accepted):", ""]
        out += table(sheader, rows)
    return out
