"""render_docs.py's sections of the registration benchmarks: raw pairs, the verdict, the good start, deskew,
odometry."""

from __future__ import annotations

import re
from pathlib import Path

from _render_format import NOT_RUN, Notes, command, ms, not_run_table, num, pct, ratio, table

# the goal docs/benchmarks.md states for the good start (ratios to GICP's)
GOAL_GOOD_START = 1.1


REG_METHODS = {
    "as-they-come": ["deepbbs++", "deepbbs++paper", "deepbbs++fast", "gicp"],
    "45deg-5m": ["deepbbs++", "deepbbs++paper", "deepbbs++fast", "gicp"],
    "any-start": ["deepbbs++", "deepbbs++local", "deepbbs++paper", "deepbbs++fast", "gicp", "kiss-matcher",
                  "kiss-matcher+gicp"],
}
REG_LABELS = {"deepbbs++": "DeepBBS++ (shipped)", "deepbbs++paper": "DeepBBS++ paper (no GICP)",
              "deepbbs++fast": "DeepBBS++ fast preset", "deepbbs++local": "DeepBBS++ without its global search",
              "gicp": "small_gicp GICP", "kiss-matcher": "KISS-Matcher", "kiss-matcher+gicp": "KISS-Matcher + GICP"}
REG_TITLES = {"as-they-come": "As they come (no initial guess):", "45deg-5m": "Source moved by up to 45 deg / 5 m:",
              "any-start": "From any start (any yaw, up to 10 m):"}


def err(c: dict | None, digits: int = 3) -> str:
    if not c or (c.get("rot_deg_mean") is None and c.get("trans_m_mean") is None):
        return "-"
    return f"{num(c.get('rot_deg_mean'), digits)} / {num(c.get('trans_m_mean'), digits)}"


def reg_share(c: dict | None, notes: Notes) -> str:
    return "-" + notes.mark("no pair of this kind in the run") if not c else pct(c["success_pct"], c["cases"])


def reg_error(c: dict | None, notes: Notes) -> str:
    if c and c.get("success_pct") == 0:
        return "-" + notes.mark("no success, so no error to average")
    return err(c)


def registration(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    fig = (doc or {}).get("figures") or {}
    kiss_every = (fig.get("settings") or {}).get("kiss_every")
    for proto, methods in REG_METHODS.items():
        header = ["method", "real: success", "real: error deg / m", "sim: success", "sim: error deg / m",
                  "p50 / p95 ms (all)", "p50 / GICP's"]
        if proto == "any-start":
            header.append("p50 / KISS-Matcher + GICP's")
        out += [REG_TITLES[proto], ""]
        n = kiss_every or 3
        every = {1: "every case", 2: "every second case", 3: "every third case"}.get(n, f"every {n}th case")
        labels = [REG_LABELS[m] + (f" ({every})" if m.startswith("kiss") else "") for m in methods]
        groups = (fig.get("protocols") or {}).get(proto)
        if groups is None:
            out += not_run_table(header, labels) + [""]
            continue
        notes = Notes()
        rows = []
        for m, label in zip(methods, labels, strict=True):
            real, sim, all_ = ((groups.get(g) or {}).get(m) for g in ("real", "sim", "all"))
            if not (real or sim or all_):
                rows.append([label] + [NOT_RUN] * (len(header) - 1))
                continue
            a = all_ or {}
            gicp = "1" if m == "gicp" else ratio(a.get("p50_over_gicp"))
            row = [label, reg_share(real, notes), reg_error(real, notes), reg_share(sim, notes),
                   reg_error(sim, notes), f"{ms(a.get('p50_ms'))} / {ms(a.get('p95_ms'))}", gicp]
            if proto == "any-start":
                km = a.get("p50_over_kiss_matcher_gicp")
                row.append("1" if m == "kiss-matcher+gicp" else
                           ratio(km) if km is not None else "-" + notes.mark("KISS-Matcher + GICP not in the run"))
            rows.append(row)
        out += table(header, rows) + notes.lines() + [""]
        if proto == "any-start" and any(m.startswith("kiss") and (groups.get("all") or {}).get(m) for m in methods):
            out += [f"KISS-Matcher runs on {every} of this protocol's cases: its p50 / p95 are over those, the "
                    "others' over all of them; the last column compares p50s over KISS-Matcher's cases only.", ""]
    a = (((fig.get("protocols") or {}).get("any-start") or {}).get("all") or {}).get("deepbbs++") or {}
    km = a.get("p50_over_kiss_matcher_gicp")
    if not doc:
        out.append(f"Speed against KISS-Matcher from any start: {NOT_RUN}.")
        return out
    times = "- (KISS-Matcher + GICP not in the run)" if km is None else f"{km:.2f}"
    out.append(f"Speed against KISS-Matcher from any start: the shipped DeepBBS++'s p50 is {times} times KISS-Matcher"
               " + GICP's (the cases KISS-Matcher ran, same run; `p50_over_kiss_matcher_gicp` in `registration.json`).")
    return out


def verdict(doc: dict | None, d: Path) -> list[str]:
    out = []
    header = ["", "share", "registrations", "score"]
    labels = ["correct results accepted (shipped pipeline, every protocol)",
              "wrong poses rejected (shipped pipeline, every protocol)",
              "correct results accepted (without the global search, any start)",
              "wrong poses rejected (without the global search, any start)", "different places rejected"]
    v = ((doc or {}).get("figures") or {}).get("verdict")
    if v is None:
        return out + not_run_table(header, labels)
    notes = Notes()
    rows = []
    for m, kind in (("deepbbs++", "shipped pipeline, every protocol"),
                    ("deepbbs++local", "without the global search, any start")):
        c = v.get(m)
        if c is None:
            rows += [[f"correct results accepted ({kind})"] + [NOT_RUN] * 3,
                     [f"wrong poses rejected ({kind})"] + [NOT_RUN] * 3]
            continue
        rows.append([f"correct results accepted ({kind})",
                     pct(c["correct_accepted_pct"]) if c["correct"] else "-" + notes.mark("no correct result"),
                     str(c["correct"]), f"lowest {num(c['lowest_correct_score'], 3)}"])
        rows.append([f"wrong poses rejected ({kind})",
                     pct(c["wrong_rejected_pct"]) if c["wrong"] else "-" + notes.mark("no wrong pose in the run"),
                     str(c["wrong"]), f"highest {num(c['highest_wrong_score'], 3)}"])
    dp = v.get("different_places")
    rows.append(["different places rejected"] + ([NOT_RUN] * 3 if dp is None else [
        pct(dp["rejected_pct"]), str(dp["pairs"]),
        f"highest {num(dp['highest_score'], 3)}; p50 {ms(dp['p50_ms'])} ms per pair"]))
    return out + table(header, rows) + notes.lines()


# ---- the good start
GS_METHODS = [("gicp", "small_gicp GICP"), ("register", "`register(T_init)`"),
              ("good_start", "`register(T_init, good_start=True)`")]


def set_label(name: str) -> str:
    """good_start.json's data set key as words: kitti_00 -> KITTI 00 (real), sim_urban -> simulated urban."""
    if name.startswith("kitti_"):
        return f"KITTI {name.removeprefix('kitti_')} (real)"
    return "simulated " + name.removeprefix("sim_").replace("_", " ") if name.startswith("sim_") else name


def gs_cell(c: dict | None, anchor: bool) -> str:
    if not c:
        return NOT_RUN
    times = f"{ms(c.get('p50_ms'))} / {ms(c.get('p99_ms'))}; CPU {ms(c.get('cpu_mean_ms'))}"
    if anchor:
        return times
    rel = f"{ratio(c.get('p50_vs_gicp'))} / {ratio(c.get('p99_vs_gicp'))}; {ratio(c.get('cpu_mean_vs_gicp'))}"
    return f"{times} ({rel})"


def gs_goal(c: dict | None) -> str:
    if not c or c.get("p50_vs_gicp") is None:
        return "-"
    missed = [w for k, w in (("p50_vs_gicp", "p50"), ("p99_vs_gicp", "p99"), ("cpu_mean_vs_gicp", "CPU"))
              if c.get(k) is not None and c[k] > GOAL_GOOD_START]
    return "met" if not missed else f"missed: {', '.join(missed)} > {GOAL_GOOD_START:g} x GICP's"


def good_start(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["raw pairs given a start", "pairs", "GICP: p50 / p99 ms; CPU ms",
              "`register(T_init)` (x GICP's)", "`good_start=True` (x GICP's)", "answered by GICP first", "goal"]
    wheader = ["starts slid along the road", "starts", "GICP alone: wrong", "`register(T_init)`: wrong accepted",
               "`good_start=True`: wrong accepted", "answered by GICP first", "goal"]
    fig = (doc or {}).get("figures") or {}
    tim, wrong = fig.get("timing"), fig.get("wrong_start")
    if tim is None:
        out += not_run_table(header, ["KITTI 00 (real)", "KITTI 02 (real)", "simulated scenes"]) + [""]
    else:
        rows = []
        for name, ms_ in tim.items():
            g, gs = ms_.get("gicp"), ms_.get("good_start")
            n = next((c["pairs"] for c in ms_.values() if c), None)
            first = "-" if not gs else pct(100 * (gs.get("paths") or {}).get("gicp", 0) / gs["pairs"])
            rows.append([set_label(name), str(n), gs_cell(g, True), gs_cell(ms_.get("register"), False),
                         gs_cell(gs, False), first, gs_goal(gs)])
        noise = fig.get("noise") or {}
        out += table(header, rows) + [
            "", f"Consecutive scans, each pair twice: from identity and from the truth moved by "
                f"{num(noise.get('trans_m'), 1)} m and {num(noise.get('yaw_deg'), 1)} deg. CPU: the mean per pair "
                "(this process and its children, read in ticks of 10 ms), the ratios in brackets p50 / p99; CPU.", ""]
    if wrong is None:
        out += not_run_table(wheader, ["every scene", "all"])
    else:
        rows = []
        for name, ms_ in wrong.items():
            if name == "calibration":
                continue
            g, r, gs = (ms_.get(m) or {} for m in ("gicp", "register", "good_start"))

            def acc(c):
                return "-" if not c else f"{c.get('accepted_wrong')} (rejected {c.get('rejected')})"
            first = "-" if not gs.get("cases") else pct(100 * (gs.get("paths") or {}).get("gicp", 0) / gs["cases"])
            ok = "-" if not gs or not r else ("met" if gs.get("accepted_wrong", 0) <= r.get("accepted_wrong", 0)
                                              else "missed: more wrong poses than `register(T_init)`")
            label = "all" if name == "all" else set_label(name) if name.startswith("kitti_") else name.replace("_", " ")
            gw = "-" if not g else f"{g.get('wrong')} ({pct(100 * (g.get('wrong_share') or 0))})"
            rows.append([label, str(g.get("cases", r.get("cases", "-"))), gw, acc(r), acc(gs), first, ok])
        shifts = ", ".join(f"{v:g}" for v in fig.get("shifts_m") or [])
        out += table(wheader, rows) + ["", f"Each pair's true pose slid {shifts} m forwards and backwards along the "
                                           "sensor's heading (GICP alone: the share and count of wrong poses; it has "
                                           "no verdict)."]
        cal = wrong.get("calibration")
        if cal:
            out += ["", calibration_line(cal)]
    return out


def calibration_line(cal: dict) -> str:
    v, s = cal.get("voxels") or {}, cal.get("sampled") or {}
    n, right = cal.get("converged"), cal.get("right")
    wrong = None if n is None or right is None else n - right
    return (f"Fitness alone (the share of points within `registration.verdict_dist` of the target, one of the "
            f"features the calibrated verdict reads), on the {n} answers of GICP within the good start's limits that "
            f"converged ({right} right, {wrong} wrong): on a spread subset of the source's GICP voxels a cut at "
            f"{num(v.get('threshold'), 3)} would take {v.get('wrong_accepted', '-')} wrong and reject "
            f"{v.get('right_rejected', '-')} right (highest wrong {num(v.get('wrong_max'), 3)}, lowest right "
            f"{num(v.get('right_min'), 3)}); on the sampled points, a cut at {num(s.get('threshold'), 3)}: highest "
            f"wrong {num(s.get('wrong_max'), 3)}, lowest right {num(s.get('right_min'), 3)}. The verdict's own "
            f"probabilities on GICP's answers from every family: `scripts/benchmarks/good_start_reach.py`.")


DESKEW = [("stream deskew", "stream deskew (default)"), ("raw", "raw"), ("pair deskew", "pair deskew"),
          ("compensated", "compensated (ceiling)"), ("gicp raw", "GICP from identity, raw")]


def deskew(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["variant", "success", "error deg / m", "translation p95 m"]
    fig = (doc or {}).get("figures")
    if fig is None:
        return out + not_run_table(header, [label for _, label in DESKEW]) + [
            "", f"The stream deskew costs {NOT_RUN} ms per scan (p50)."]
    rows = []
    for key, label in DESKEW:
        a = (fig["variants"].get(key) or {}).get("all")
        rows.append([label] + ([NOT_RUN] * 3 if a is None else [
            pct(a["success_pct"], a["pairs"]), err(a, 4), num(a.get("trans_m_p95"), 4)]))
    p50 = (fig.get("stream_deskew_ms") or {}).get("p50")
    return out + table(header, rows) + ["", f"The stream deskew costs {ms(p50)} ms per scan (p50)."]


def odo_label(run: str) -> str:
    m = re.fullmatch(r"sim (\w+) (\d+)f (\S+)", run)
    if m:
        scene, frames, variant = m.groups()
        what = {"clean": "as it is", "drop": "8 gaps of dropped scans", "wrong-prior": "10 wrong priors"}
        return f"simulated {scene}, {frames} scans, {what.get(variant, variant)}"
    m = re.fullmatch(r"KITTI (\S+)", run)
    return f"KITTI {m.group(1)}" if m else run


def odo_cell(v: dict | None, m: str, notes: Notes) -> str:
    if v is None:
        return "-" + notes.mark(f"{m} not run on this variant (once it diverges a scan takes seconds)"
                                if m == "kiss-icp" else f"{m} not in the run")
    drift = num(v.get("kitti_t_err_pct"), 2)
    if v.get("kitti_t_err_pct") is None:
        drift += notes.mark("no segment of 100 m or longer: KITTI's drift is not defined")
    failed = v.get("failed_frames")
    return f"{drift} / {num(v.get('ate_rmse_m'), 3)}" + (notes.mark(f"{failed} failed frame(s)") if failed else "")


def odometry(doc: dict | None, d: Path) -> list[str]:
    out = command(doc)
    header = ["run", "scans", "DeepBBS++ drift % / ATE m", "KISS-ICP", "GICP",
              "DeepBBS++ frames/s (x KISS-ICP's)"]
    fig = (doc or {}).get("figures")
    if fig is None:
        return out + not_run_table(header, ["simulated urban, 500 scans, as it is",
                                            "simulated urban, 500 scans, 8 gaps of dropped scans",
                                            "simulated urban, 500 scans, 10 wrong priors", "KITTI 00", "KITTI 02"])
    notes = Notes()
    rows = []
    for run, r in fig["runs"].items():
        ms_ = r["methods"]
        dbb = ms_.get("deepbbs++") or {}
        fps = num(dbb.get("fps"), 1)
        if dbb.get("fps_over_kiss_icp") is not None:
            fps += f" ({ratio(dbb['fps_over_kiss_icp'])})"
        label = odo_label(run) + ("" if r.get("complete", True) else notes.mark("the run did not complete"))
        frames = dbb.get("frames") or next((v.get("frames") for v in ms_.values()), None)
        rows.append([label, str(frames) if frames is not None else "-",
                     *(odo_cell(ms_.get(m), m, notes) for m in ("deepbbs++", "kiss-icp", "gicp")), fps])
    return out + table(header, rows) + notes.lines()
