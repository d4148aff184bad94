"""The tables of docs/sensors.md from families.json (scripts/benchmarks/families.py), for render_docs.py."""

from __future__ import annotations

SENSOR_LABELS = {"hdl64": "Velodyne HDL-64E", "hdl32": "Velodyne HDL-32E", "vlp16": "Velodyne VLP-16",
                 "ouster64": "Ouster OS1-64 (older preset)", "os0_32": "Ouster OS0-32", "os0_64": "Ouster OS0-64",
                 "os0_128": "Ouster OS0-128", "os1_32": "Ouster OS1-32", "os1_64": "Ouster OS1-64",
                 "os1_128": "Ouster OS1-128", "xt32": "Hesai XT-32", "helios32": "RoboSense-like 32 beams",
                 "avia": "Livox Avia", "mid360": "Livox Mid-360"}
REAL_LABELS = {"kitti": "KITTI {}", "pair": "reference pair", "nuscenes": "nuScenes", "livox": "handheld walk"}
METHODS = ("deepbbs++", "gicp", "kiss-matcher+gicp")
HEADER = ["LiDAR", "data", "pairs", "overlap p50", "DeepBBS++", "GICP", "KISS-Matcher + GICP",
          "errors where both are right, deg / m: DeepBBS++; GICP",
          "verdict: wrong accepted / right rejected (beyond 2 deg / 0.5 m; within 1 deg / 0.3 m)",
          "DeepBBS++ p50 / p95 ms", "p50 / GICP's", "`good_start=True`: success", "its p50 / GICP's",
          "its GICP path accepted", "start in GICP's basin: pairs (others)", "there: its p50 / GICP's",
          "there: its paths"]
GOOD = "deepbbs++good"


def data_label(name: str, c: dict) -> str:
    if c.get("source") == "real":
        kind, _, rest = name.partition("_")
        return "real, " + REAL_LABELS.get(kind, kind).format(rest)
    return f"simulated, {c.get('mount')}, {c.get('place')}"


def _order(fig: dict) -> list[str]:
    rank = list(SENSOR_LABELS)
    return sorted(fig, key=lambda n: (rank.index(fig[n]["sensor"]) if fig[n]["sensor"] in rank else 99,
                                      fig[n]["source"] != "real", n))


def _pct(v, n) -> str:
    return "-" if v is None else f"{v:.1f} % ({n})"


def _err(b: dict, m: str) -> str:
    r, t = b.get(f"{m}_rot_median"), b.get(f"{m}_trans_median")
    return "-" if r is None else f"{r:.3f} / {t:.3f}"


def _row(name: str, c: dict) -> list[str]:
    s, n = c["success_pct"], c["pairs"]
    b, v = c.get("both_right") or {}, c.get("verdict") or {}
    ratio = (c.get("p50_over_gicp") or {}).get("deepbbs++")
    return [SENSOR_LABELS.get(c["sensor"], c["sensor"]), data_label(name, c), str(n), f"{c['overlap_median']:.2f}",
            *(_pct(s.get(m), n) for m in METHODS), f"{_err(b, 'deepbbs++')}; {_err(b, 'gicp')} ({b.get('pairs', 0)})",
            f"{v.get('accepted_wrong', '-')} / {v.get('rejected_right', '-')} (of {v.get('cases', '-')}"
            + (f"; {v['accepted_between']} in between accepted)" if v.get("accepted_between") else ")"),
            _ms(c, "deepbbs++"),
            "-" if ratio is None else f"x{ratio:.2f}", *_good(c)]


def _ms(c: dict, m: str) -> str:
    return "-" if m not in c["p50_ms"] else f"{c['p50_ms'][m]:.0f} / {c['p95_ms'][m]:.0f}"


def _good(c: dict) -> list[str]:
    g, ratio = c.get("good_start"), (c.get("p50_over_gicp") or {}).get(GOOD)
    if not g:
        return ["-"] * 6
    return [_pct(c["success_pct"][GOOD], g["pairs"]), "-" if ratio is None else f"x{ratio:.2f}",
            f"{g['gicp_path']} of {g['pairs']}", *_basin(c.get("good_start_in_basin"))]


def _basin(b: dict | None) -> list[str]:
    """The good start over the pairs whose start lies in GICP's basin (families.in_basin): how many (and how many
    not), its p50 over GICP's there, the paths that answered."""
    if not b:
        return ["-", "-", "-"]
    ratio, alt = b.get("p50_over_gicp"), b.get("alternated")
    text = "-" if ratio is None else f"x{ratio:.2f}"
    if alt:  # timed again alternately (families.alternate): that ratio, the first timings' beside it
        text = f"x{alt['p50_over_gicp']:.2f} (first timings {text})"
    counts: dict[str, int] = {}
    for k, v in (b.get("paths") or {}).items():  # "within reach": figures from before the name "beyond limits"
        k = "beyond limits" if k == "within reach" else k
        counts[k] = counts.get(k, 0) + v
    paths = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    return [f"{b['pairs']} ({b['others']})", text, paths or "-"]


def _missed(name: str, c: dict) -> list[str]:
    out = []
    for x in c.get("missed") or []:
        rot, tr = x["truth_gicp_deg_m"]
        out.append(f"- {SENSOR_LABELS.get(c['sensor'], c['sensor'])}, {data_label(name, c)}: scan {x['i']} to "
                   f"{x['j']} ({x['dist_m']:.1f} m apart), overlap {x['overlap']:.2f}; DeepBBS++ off by "
                   f"{x['rot_deg']:.2f} deg / {x['trans_m']:.2f} m, {'accepted' if x['accepted'] else 'rejected'}; "
                   f"GICP {'right' if x['gicp_ok'] else 'wrong too'}; GICP started at the truth moves "
                   f"{rot:.2f} deg / {tr:.2f} m")
    return out


def families(doc: dict | None, command: list[str], not_run: str) -> list[str]:
    """The good-start table, the DeepBBS++ misses and the basin table (``not_run`` rows without a JSON)."""
    fig = ((doc or {}).get("figures") or {}).get("sets")
    if not fig:
        return ["Good start (neighbouring scans as recorded): " + not_run + ".", "",
                "From moved starts (the basin): " + not_run + "."]
    out = command + ["Good start (neighbouring scans as recorded): success within 1 deg / 0.3 m per method "
                     "(pairs in brackets), overlap = share of source points within 0.5 m of the target at the truth; "
                     "the verdict's counts are over every start of the set. `good_start=True`: DeepBBS++ told that "
                     "the start is good (`register(..., good_start=True)`, as the node does with `node.good_start`): "
                     "GICP from it, accepted by a stricter verdict, else the full pipeline. Start in GICP's basin: "
                     "the pairs whose start is good by a physical criterion, GICP from it lands within 1 deg / 0.3 m "
                     "(in brackets the pairs where it does not, from which GICP alone fails); there, the p50 of "
                     "`good_start=True` over GICP's on the same pairs (both timed again on each pair, alternately, "
                     "the medians' ratio; in brackets that of the first timings, the good start's right after the "
                     "full pipeline's), and the path that answered: `gicp` (GICP "
                     "from the start within the good start's limits), `beyond limits` (converged beyond them, taken "
                     "as the verdict accepted it), `coarse to fine` (the second try), or the full pipeline (`deepbbs`, "
                     "`search`) when neither was taken.", ""]
    out += ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    out += ["| " + " | ".join(_row(n, fig[n])) + " |" for n in _order(fig)]
    missed = [line for n in _order(fig) for line in _missed(n, fig[n])]
    out += ["", "Pairs DeepBBS++ misses from the good start:" if missed else
            "DeepBBS++ misses no pair from the good start.", "", *missed, ""]
    basin = (doc.get("figures") or {}).get("basin") or []
    head = ["LiDAR", "data"] + [f"{y:.0f} deg / {s:.0f} m" for y, s in basin]
    out += ["From moved starts (the basin): success of DeepBBS++ / GICP / KISS-Matcher + GICP in % when the source "
            "is turned by the yaw and shifted by the distance of the column (random sign and direction).", "",
            "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for n in _order(fig):
        c = fig[n]
        cells = {(b["yaw_deg"], b["shift_m"]): b for b in c.get("basin") or []}
        row = [SENSOR_LABELS.get(c["sensor"], c["sensor"]), data_label(n, c)]
        for y, s in basin:
            b = cells.get((y, s))
            row.append("-" if b is None else " / ".join(f"{b['success_pct'][m]:.0f}" for m in METHODS
                                                        if m in b["success_pct"]) + f" ({b['cases']})")
        out.append("| " + " | ".join(row) + " |")
    return out


def sensor_defaults() -> list[str]:
    """The ``preprocess.sensor`` rows (SENSORS in deepbbs_ros/config/preprocess.py): what each one changes, and why."""
    from deepbbs_ros.config.preprocess import SENSORS, PreprocessConfig

    generic = PreprocessConfig()
    rows = []
    for name, row in SENSORS.items():
        if not row:
            rows.append(f"| `{name}` | the defaults | |")
        for k, (v, why) in row.items():
            rows.append(f"| `{name}` | `preprocess.{k}`: {v} (default {getattr(generic, k)}) | {why} |")
    return ["| `preprocess.sensor` | what it changes | why |", "|---|---|---|", *rows]
