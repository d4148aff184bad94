"""The per-family registration benchmark (scripts/benchmarks/families.py): its overlap, its plan of starts, its
summary and the tables of docs/sensors.md rendered from it, on tiny synthetic inputs."""

from __future__ import annotations

import sys
from argparse import Namespace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts" / "benchmarks"))

import _families_doc  # noqa: E402
import families  # noqa: E402


def _cloud(n=400, seed=0):
    return np.random.default_rng(seed).uniform(-10, 10, (n, 3)).astype(np.float32)


def test_overlap_is_the_share_of_source_points_near_the_target_at_the_truth():
    tgt = _cloud()
    T = np.eye(4)
    T[:3, 3] = [3.0, 0.0, 0.0]
    src = tgt - T[:3, 3]  # p_target = p_source + t: the same points
    assert families.overlap(src, tgt, T) == 1.0
    assert families.overlap(src, tgt, np.eye(4)) < 0.5  # 3 m off: few points within 0.5 m
    half = np.vstack([src[:200], src[200:] + [0, 0, 100.0]])  # half the source sees nothing of the target
    assert families.overlap(half, tgt, T) == 0.5


def test_plan_covers_every_basin_offset_with_exact_moves():
    sets = {"sim_a": {"pairs": [(k, k - 1) for k in range(1, 7)]}, "pair_p": {"pairs": [(1, 0)]}}
    args = Namespace(pairs_per_set=4, basin_pairs=2, pair_trials=3, seed=1)
    cases = families.plan(sets, args)
    a = [c for c in cases if c["set"] == "sim_a"]
    assert sum(c["level"] == 0 for c in a) == 4 and all(sum(c["level"] == k for c in a) == 2 for k in range(1, 6))
    assert sum(c["set"] == "pair_p" for c in cases) == 1 + 3 * 5
    for c in cases:
        yaw, shift = families.BASIN[c["level"]]
        assert abs(abs(c["move"][0]) - yaw) < 1e-9 and abs(np.hypot(*c["move"][1:]) - shift) < 1e-9
    assert families.plan(sets, args) == cases  # deterministic


def _rec(level, deep_ok, valid, gicp_ok=True):
    good = {"deepbbs++good": {"ok": True, "valid": True, "score": 0.9, "ms": 60.0, "rot": 0.1, "trans": 0.02,
                              "path": "gicp"}} if level == 0 else {}
    return {**good, "set": "sim_vlp16_wheeled_hall", "i": 1, "j": 0, "level": level, "overlap": 0.8, "dist": 1.0,
            "deepbbs++": {"ok": deep_ok, "valid": valid, "score": 0.5, "ms": 100.0, "rot": 0.1 if deep_ok else 9.0,
                          "trans": 0.02 if deep_ok else 2.0},
            "gicp": {"ok": gicp_ok, "ms": 50.0, "rot": 0.2, "trans": 0.03}}


def test_summary_and_its_tables():
    tgt = _cloud()
    sets = {"sim_vlp16_wheeled_hall": {"sensor": "vlp16", "source": "sim", "mount": "wheeled", "place": "hall",
                                       "frames": [(tgt, np.eye(4)), (tgt, np.eye(4))]}}
    recs = [_rec(0, True, True), _rec(0, False, True), _rec(0, True, False), _rec(5, True, True, gicp_ok=False)]
    fig = families.summarise(recs, sets, ["deepbbs++", "deepbbs++good", "gicp"])
    c = fig["sim_vlp16_wheeled_hall"]
    assert c["pairs"] == 3 and abs(c["success_pct"]["deepbbs++"] - 200 / 3) < 1e-9
    assert c["verdict"] == {"cases": 4, "accepted_wrong": 1, "accepted_between": 0, "rejected_right": 1, "right": 3}
    # a pose accepted 1.5 deg / 0.1 m off is neither right nor wrong: counted apart, not as a wrong acceptance
    between = _rec(5, False, True)
    between["deepbbs++"].update(rot=1.5, trans=0.1)
    v = families.summarise(recs + [between], sets, ["deepbbs++", "deepbbs++good", "gicp"])["sim_vlp16_wheeled_hall"]
    assert (v["verdict"]["accepted_wrong"], v["verdict"]["accepted_between"]) == (1, 1)
    assert c["both_right"]["pairs"] == 2 and c["both_right"]["gicp_trans_median"] == 0.03
    assert c["p50_over_gicp"]["deepbbs++"] == 2.0
    (miss,) = c["missed"]
    assert miss["overlap"] == 0.8 and miss["accepted"] and max(miss["truth_gicp_deg_m"]) < 0.05  # same cloud
    assert [b["yaw_deg"] for b in c["basin"]] == [0.0, 180.0]
    doc = {"command": "scripts/benchmarks/families.py --quick", "figures": {"sets": fig, "basin": families.BASIN}}
    text = "\n".join(_families_doc.families(doc, ["Measured by x."], "not run"))
    assert "| Velodyne VLP-16 | simulated, wheeled, hall | 3 | 0.80 | 66.7 % (3) | 100.0 % (3) | - |" in text
    assert "1 / 1 (of 4)" in text and "x2.00" in text and "overlap 0.80" in text
    assert c["good_start"] == {"pairs": 3, "gicp_path": 3, "degenerate": 0, "coarse_to_fine": 0, "fallback_why": {},
                               "beyond_limits": 0, "stages_p50_ms": {}, "accepted_wrong": 0, "rejected_right": 0}
    assert families._stages([{"stages_ms": {"preprocess": 4.0, "good_start": 2.0, "total": 6.0}},
                             {"stages_ms": {"preprocess": 6.0, "good_start": 3.0, "global": 90.0, "total": 99.0}}]) == {
        "global": 45.0, "good_start": 2.5, "preprocess": 5.0, "total": 52.5}
    assert families._whys(["GICP from the start: not converged in 9 iterations; coarse to fine: verdict 0.8 < x",
                           "verdict 0.42 < registration.good_start_probability 0.7"]) == {
        "not converged / verdict": 1, "verdict": 1}
    assert "| 100.0 % (3) | x1.20 | 3 of 3 |" in text
    assert "deepbbs++good" not in c["basin"][1]["success_pct"]
    assert "not run" in "\n".join(_families_doc.families(None, [], "not run"))


def test_sensor_defaults_table_names_every_sensor_row():
    from deepbbs_ros.core.sensors import SENSORS

    text = "\n".join(_families_doc.sensor_defaults())
    assert all(f"`{name}`" in text for name in SENSORS)
    assert "`preprocess.voxel_size`: 0.2 (default 0.3)" in text


def _good_rec(gicp_ok, path, why, ms, ok=True, valid=True):
    return {"set": "sim_a", "i": 1, "j": 0, "level": 0, "overlap": 0.8, "dist": 1.0,
            "gicp": {"ok": gicp_ok, "ms": 10.0, "cpu_ms": 15.0},
            "deepbbs++good": {"ok": ok, "valid": valid, "ms": ms, "cpu_ms": 1.5 * ms, "path": path, "why": why}}


def test_good_start_where_the_start_lies_in_gicps_basin():
    """families.in_basin: the good-start pairs whose start is good by a physical criterion (GICP from it is right) are
    summarised apart: how many and how many not, the p50 ratio over them (wall and CPU), the path each took."""
    recs = [_good_rec(True, "gicp", "accepted", 12.0),
            _good_rec(True, "gicp", "accepted, beyond the good start's limits (GICP from the start: moved)", 14.0),
            _good_rec(True, "search", "GICP from the start: turned 24 deg; coarse to fine: verdict 0.5 < x", 400.0),
            _good_rec(False, "search", "GICP from the start: not converged in 18 iterations; coarse to fine: x", 900.0,
                      ok=False, valid=False),
            _good_rec(False, "gicp", "accepted after coarse to fine (GICP from the start: moved)", 30.0)]
    b = families.in_basin(recs)
    assert b["pairs"] == 3 and b["others"] == 2
    assert b["p50_ms"] == {"deepbbs++good": 14.0, "gicp": 10.0} and b["p50_over_gicp"] == 1.4
    assert b["cpu_p50_over_gicp"] == 1.5 * 14.0 / 15.0
    assert b["paths"] == {"gicp": 1, "beyond limits": 1, "search": 1}
    assert b["fallback_why"] == {"moved / verdict": 1} and b["accepted_wrong"] == 0 and b["rejected_right"] == 0
    assert families.in_basin(recs[3:]) == {"pairs": 0, "others": 2}
    sets = {"sim_a": {"sensor": "vlp16", "source": "sim", "mount": "wheeled", "place": "hall",
                      "frames": [(_cloud(), np.eye(4))] * 2}}
    c = families.summarise(recs, sets, ["deepbbs++good", "gicp"])["sim_a"]
    assert c["good_start_in_basin"] == b and c["p50_over_gicp"]["deepbbs++good"] == 3.0  # all pairs: 30 / 10
    assert c["cpu_p50_over_gicp"]["deepbbs++good"] == 45.0 / 15.0
    doc = {"command": "x", "figures": {"sets": {"sim_a": c}, "basin": families.BASIN}}
    text = "\n".join(_families_doc.families(doc, [], "not run"))
    row = next(line for line in text.splitlines() if "VLP-16" in line and "of 5" in line)
    assert row.endswith("| 3 of 5 | 3 (2) | x1.40 | beyond limits 1, gicp 1, search 1 |"), row


class _Timed:
    """A registration stand-in that records the order it is called in."""

    def __init__(self, name, calls):
        self.name, self.calls = name, calls

    def register(self, src, tgt, T_init=None, good_start=False):
        self.calls.append(self.name)
        return None


def test_good_start_and_gicp_are_timed_again_alternately(monkeypatch):
    """families.alternate: the good start and GICP timed on the same pair in alternating order (neither always in
    the other's wake); in_basin gives the ratio of their medians beside the first timings', and the table shows it
    with the first timings' in brackets."""
    calls = []
    monkeypatch.setattr(families._reg, "_register", lambda m, reg, s, t: reg.register(s, t))
    out = families.alternate(_Timed("good", calls), _Timed("gicp", calls), _cloud(), _cloud(), 3)
    assert calls == ["gicp", "good", "good", "gicp", "gicp", "good"]
    assert sorted(out) == ["gicp_cpu_ms", "gicp_ms", "good_cpu_ms", "good_ms"]
    assert all(len(v) == 3 for v in out.values())
    recs = [_good_rec(True, "gicp", "accepted", 12.0), _good_rec(True, "gicp", "accepted", 14.0)]
    recs[0]["timing"] = {"good_ms": [11.0, 30.0, 12.0], "gicp_ms": [10.0, 10.0, 11.0], "good_cpu_ms": [11.0] * 3,
                         "gicp_cpu_ms": [10.0] * 3}
    assert "alternated" not in families.in_basin(recs)  # one pair without them: none
    recs[1]["timing"] = {"good_ms": [13.0] * 3, "gicp_ms": [12.0] * 3, "good_cpu_ms": [14.0] * 3,
                         "gicp_cpu_ms": [12.0] * 3}
    b = families.in_basin(recs)
    assert b["alternated"] == {"repeats": 3, "p50_ms": {"deepbbs++good": 12.5, "gicp": 11.0},
                               "p50_over_gicp": 12.5 / 11.0, "cpu_p50_over_gicp": 12.5 / 11.0}
    assert b["p50_over_gicp"] == 1.3  # the first timings' (13 / 10)
    assert _families_doc._basin(b)[1] == "x1.14 (first timings x1.30)"


class _Streamed(_Timed):
    """A stand-in for both methods as a stream calls them: the target prepared first (untimed), then the call."""

    def preprocess(self, points, lazy=False):
        self.calls.append(self.name + " prepares")
        return ("prepared", points)

    def align(self, src, tgt):
        self.calls.append(self.name)

    def register(self, src, tgt, T_init=None, good_start=False):
        self.calls.append(self.name if isinstance(tgt, np.ndarray) else self.name + " on a prepared target")


def test_stream_timing_prepares_the_target_before_the_clock_and_alternates(monkeypatch):
    """families.alternate(stream=True): each round times the raw pair as before, then both as in a stream (the target
    prepared before the clock starts, afresh each round), in the same alternating order; in_basin gives that ratio
    apart."""
    calls = []
    monkeypatch.setattr(families._reg, "_register", lambda m, reg, s, t: reg.register(s, t))
    monkeypatch.setattr(families, "timed", lambda call, reg: (call(reg), 1.0, 1.0))
    out = families.alternate(_Streamed("good", calls), _Streamed("gicp", calls), _cloud(), _cloud(), 2, stream=True)
    assert calls == ["gicp", "good", "gicp prepares", "gicp prepares", "gicp", "good prepares",
                     "good on a prepared target",
                     "good", "gicp", "good prepares", "good on a prepared target", "gicp prepares", "gicp prepares",
                     "gicp"]
    assert sorted(out) == sorted(f"{m}{s}_{k}" for m in ("good", "gicp") for s in ("", "_stream")
                                 for k in ("ms", "cpu_ms"))
    recs = [_good_rec(True, "gicp", "accepted", 12.0)]
    recs[0]["timing"] = {**out, "good_stream_ms": [6.0, 6.0], "gicp_stream_ms": [4.0, 4.0]}
    assert families.in_basin(recs)["alternated"]["stream"]["p50_over_gicp"] == 1.5


def test_node_timing_prepares_both_scans_before_the_clock(monkeypatch):
    """families.alternate(node=True): each round also times both on scans prepared before the clock starts, as the
    node's registration process holds them in a stream (the good start's target made ready to judge:
    core.scans.ready_to_judge); in_basin gives that ratio apart."""
    calls, clocked = [], []
    monkeypatch.setattr(families._reg, "_register", lambda m, reg, s, t: reg.register(s, t))

    def timed(call, reg):
        clocked.append(len(calls))
        out = call(reg)
        clocked.append(len(calls))
        return out, 1.0, 1.0

    monkeypatch.setattr(families, "timed", timed)
    monkeypatch.setattr("deepbbs_ros.core.scans.ready_to_judge", lambda cfg, pre: calls.append("ready") or pre)
    good, gicp = _Streamed("good", calls), _Streamed("gicp", calls)
    good.config = gicp.config = None
    out = families.alternate(good, gicp, _cloud(), _cloud(), 1, node=True)
    assert calls == ["gicp", "good", "gicp prepares", "gicp prepares", "gicp", "good prepares", "good prepares",
                     "ready", "good on a prepared target"]
    assert [calls[a:b] for a, b in zip(clocked[::2], clocked[1::2])] == [["gicp"], ["good"], ["gicp"],
                                                                         ["good on a prepared target"]]
    assert sorted(out) == sorted(f"{m}{s}_{k}" for m in ("good", "gicp") for s in ("", "_node")
                                 for k in ("ms", "cpu_ms"))
    recs = [_good_rec(True, "gicp", "accepted", 12.0)]
    recs[0]["timing"] = {**out, "good_node_ms": [5.0], "gicp_node_ms": [4.0]}
    assert families.in_basin(recs)["alternated"]["node"]["p50_over_gicp"] == 1.25


def test_the_good_start_alone_is_run_summarised_and_reported(tmp_path, monkeypatch, capsys):
    """--methods deepbbs++good alone: it applies to the good start only, so the basin offsets' cases have no record;
    collect returns the recorded ones, and the summary and the report are made of them."""
    monkeypatch.setattr(families._reg, "make_methods", lambda names, args: {n: ("timed", "answering") for n in names})
    monkeypatch.setattr(families, "run_good", lambda regs, src, tgt: {
        "ms": 5.0, "cpu_ms": 6.0, "T": np.eye(4), "valid": True, "score": 0.9, "path": "gicp", "why": "accepted",
        "stages_ms": {}})
    sets = {"sim_a": {"sensor": "vlp16", "source": "sim", "mount": "wheeled", "place": "hall",
                      "frames": [(_cloud(seed=k), np.eye(4)) for k in range(2)]}}
    cases = [{"set": "sim_a", "i": 1, "j": 0, "level": level, "move": [30.0 * level, 2.0 * level, 0.0]}
             for level in (0, 1)]
    args = Namespace(report_only=False, timing_repeats=3)
    recs = families.collect(cases, sets, [families.GOOD], args, tmp_path / "cases.jsonl")
    assert [r["level"] for r in recs] == [0] and recs[0][families.GOOD]["ok"]
    fig = families.summarise(recs, sets, [families.GOOD])
    assert fig["sim_a"]["good_start"]["gicp_path"] == 1 and fig["sim_a"]["success_pct"] == {families.GOOD: 100.0}
    families.report(fig, [families.GOOD])
    assert "deepbbs++good 100 %" in capsys.readouterr().out
    assert families.collect(cases, sets, [families.GOOD], args, tmp_path / "cases.jsonl") == recs  # a rerun reads it


def test_a_degenerate_good_start_answer_is_not_counted_as_gicps_path():
    """A good start answered at once, not valid, degenerate (core/finish_verdict.py) has path "gicp" but is its own
    path in the summaries, not one GICP's path took."""
    x = {"path": "gicp", "valid": False, "why": "not valid: degenerate along a roll about x (free by 13 tolerances)"}
    assert families.path_taken(x) == "degenerate"
    assert families.path_taken({"path": "gicp", "valid": True, "why": "accepted"}) == "gicp"
