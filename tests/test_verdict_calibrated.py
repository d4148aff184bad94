"""The calibrated verdict: visibility features (seen / free-space violation / unknown), the shipped coefficients,
and a probability that separates a right pose from a wrong one (core/visibility.py, core/calibrated.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from deepbbs_ros.core import calibrated, verdict, visibility
from deepbbs_ros.errors import ConfigError, VerdictModelError


def _room(rng: np.random.Generator, n: int = 4000) -> np.ndarray:
    """Returns of a sensor at the origin inside a 20 x 12 x 4 m box room (walls, floor, ceiling) with a pillar."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    half = np.array([10.0, 6.0, 2.0])
    t = np.min(half / np.maximum(np.abs(d), 1e-9), axis=1)  # the box's face along each ray
    return (d * t[:, None]).astype(np.float64)


def _shifted(T_shift: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ T_shift[:3, :3].T + T_shift[:3, 3]


def test_features_see_a_right_pose_and_the_free_space_a_wrong_one_violates():
    rng = np.random.default_rng(0)
    target = _room(rng)
    source = _room(np.random.default_rng(1), 1500)
    right = visibility.pose_features(source, np.eye(4), target, 0.5)
    f = dict(zip(visibility.FEATURES, right, strict=True))
    assert f["fitness"] > 0.95 and f["consistency"] > 0.99 and f["violations"] < 0.01, f
    T = np.eye(4)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    T[:2, :2], T[0, 3] = [[c, -s], [s, c]], -2.0  # turned 30 deg: walls land in the room, where the target saw through
    wrong = dict(zip(visibility.FEATURES, visibility.pose_features(source, T, target, 0.5), strict=True))
    assert wrong["violations"] > 0.05 and wrong["consistency"] < f["consistency"] - 0.05, wrong
    assert calibrated.probability(right) > 0.9 > calibrated.probability(visibility.pose_features(source, T, target,
                                                                                                 0.5))


def test_points_behind_the_target_or_outside_its_view_say_nothing():
    target = np.array([[5.0, y, z] for y in np.linspace(-2, 2, 21) for z in np.linspace(-1, 1, 11)])  # a wall ahead
    behind = target + np.array([4.0, 0.0, 0.0])  # occluded by the wall
    aside = target[:, [1, 0, 2]] * np.array([1.0, -1.0, 1.0])  # a wall to the right: no target return there
    for pts in (behind, aside):
        f = dict(zip(visibility.FEATURES, visibility.pose_features(pts, np.eye(4), target, 0.5), strict=True))
        assert f["fitness"] == 0 and f["violations"] == 0 and f["observable"] == 0, f
    front = target * 0.4  # 3 m in front of the wall, in the same directions: the target saw through it
    f = dict(zip(visibility.FEATURES, visibility.pose_features(front, np.eye(4), target, 0.5), strict=True))
    assert f["violations"] == 1.0 and f["consistency"] == 0.0, f


def test_cell_size_follows_the_target_density():
    rng = np.random.default_rng(2)
    dense, sparse = _room(rng, 40000), _room(rng, 2000)
    cells = [visibility.cell_size(*visibility._angles(p)[:2]) for p in (dense, sparse)]
    assert cells[0] < cells[1], cells


def test_shipped_coefficients_load_and_a_damaged_file_is_one_line(tmp_path):
    models = calibrated.load()
    assert {"pair", "good_start"} <= set(models)
    doc = json.loads(calibrated.DEFAULT_PATH.read_text())
    assert doc["command"].startswith("python scripts/calibrate_verdict.py")
    with pytest.raises(VerdictModelError, match="verdict_model|missing|No such file") as e:
        calibrated.load(str(tmp_path / "missing.json"))
    assert "\n" not in str(e.value)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**doc, "models": {"pair": {"coef": [1.0], "intercept": 0.0}}}))
    with pytest.raises(VerdictModelError, match="finite coefficients"):
        calibrated.load(str(bad))


def test_a_floor_on_pinned_vetoes_a_pose_the_fit_leaves_free(tmp_path):
    """A coefficients file may set ``min_pinned``: a pose pinned less has probability 0; others are unchanged."""
    doc = json.loads(calibrated.DEFAULT_PATH.read_text())
    floored = tmp_path / "floored.json"
    floored.write_text(json.dumps({**doc, "min_pinned": 0.02}))
    unfloored = tmp_path / "unfloored.json"
    unfloored.write_text(json.dumps({**doc, "min_pinned": 0.0}))
    rows = np.full((2, len(visibility.FEATURES)), 0.95)
    rows[0, visibility.FEATURES.index("pinned")] = 0.019
    rows[1, visibility.FEATURES.index("pinned")] = 0.021
    p = calibrated.probability(rows, "good_start", str(floored))
    plain = calibrated.probability(rows, "good_start", str(unfloored))
    assert p[0] == 0.0 and plain[0] > 0.0 and p[1] == plain[1] > 0.0
    assert calibrated.probability(rows[1], "good_start", str(floored)) == pytest.approx(p[1])
    assert calibrated.min_pinned(str(floored)) == 0.02 and calibrated.min_pinned(str(unfloored)) == 0.0
    assert calibrated.min_pinned() == doc.get("min_pinned", 0.0)
    bad = tmp_path / "bad_floor.json"
    bad.write_text(json.dumps({**doc, "min_pinned": 1.5}))
    with pytest.raises(VerdictModelError, match="min_pinned"):
        calibrated.load(str(bad))


def test_probability_is_empty_safe_and_the_setting_is_checked():
    assert verdict.probability(np.zeros((0, 3)), np.eye(4), np.ones((5, 3)), 0.5) == 0.0
    from deepbbs_ros.config import Config

    with pytest.raises(ConfigError, match="registration.verdict_probability"):
        Config.from_dict({"registration": {"verdict_probability": 1.5}})


def test_a_feature_left_out_of_the_fit_gets_no_weight():
    """scripts/calibrate_verdict.py can leave features out of the fit (coefficient 0), and the shipped model is
    fitted with scripts/calibrate_verdict.py's UNUSED ones left out."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import calibrate_verdict as cv

    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, len(visibility.FEATURES)))
    y = (X[:, 0] + 0.5 * X[:, 2] + rng.normal(0, 0.3, 200) > 0).astype(float)
    coef, _ = cv.fit_logistic(X, y, unused=("plane_close",))
    i = visibility.FEATURES.index("plane_close")
    assert coef[i] == 0.0 and coef[0] > 0
    for name in ("pair", "good_start", "pair_relative", "good_start_relative"):
        for f in cv.UNUSED:
            assert calibrated.load()[name][0][visibility.FEATURES.index(f)] == 0.0


def test_low_overlap_pairs_let_the_target_judge_a_small_share_and_hold_a_right_pose():
    """scripts/calibrate_verdict.py's low-overlap pairs (a sensor turned between the scans) have the overlap asked
    for at the truth, and give right poses there as well as wrong ones."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import calibrate_verdict as cv

    rig = cv.LOW_RIGS.index(("mid360", "legged", "courtyard"))
    d = cv.collect(cv.LOW_RIGS[rig:rig + 1], 38, 2, low=True, rig0=len(cv.RIGS) + rig, log=lambda *_: None)
    assert len(d["y"]) and np.all(d["rig"] == len(cv.RIGS) + rig)
    right = d["y"] == 1
    obs = d["good"][right, visibility.FEATURES.index("observable")]
    assert right.any() and (~right).any()
    assert np.all(obs <= cv.LOW_OVERLAP[1] + 0.1), obs  # right poses: about the truth's share


def test_relative_shares_are_read_over_the_overlap_the_pose_expects(tmp_path):
    """A file's ``"relative"`` models read the shares over ``in_view``: a right pose of a narrow sensor turned by half
    its view (half of the source in view, all of that seen) reads as one that saw everything; with nothing in view, 0.
    They judge only a pose the fit holds (pinned or anchored_far at their bounds); one that can slide is judged by the
    plain model. The field of view is then measured (``weighs``), anchored_far under the bound; bad files refused."""
    shipped = json.loads(calibrated.DEFAULT_PATH.read_text())
    m = {k: shipped["models"][k] for k in ("pair", "good_start")}
    doc = {**{k: v for k, v in shipped.items() if k != "relative"}, "models": m}  # the plain models only
    plain_path = tmp_path / "plain.json"
    plain_path.write_text(json.dumps(doc))
    models = {**m, "pair_relative": m["pair"], "good_start_relative": m["good_start"]}
    spec = {"shares": ["fitness", "observable"], "held_pinned": 0.03, "held_anchored_far": 0.1}
    path = tmp_path / "rel.json"
    path.write_text(json.dumps({**doc, "models": models, "relative": spec}))
    f = {n: visibility.FEATURES.index(n) for n in ("fitness", "observable", "in_view", "pinned", "anchored_far")}
    rows = np.full((4, len(visibility.FEATURES)), 0.9)
    rows[:, f["in_view"]] = [1.0, 0.5, 0.0, 0.5]
    rows[:, f["fitness"]] = rows[:, f["observable"]] = [0.9, 0.45, 0.0, 0.45]
    rows[3, f["pinned"]], rows[3, f["anchored_far"]] = 0.01, 0.05  # free to slide: the plain model
    rel = calibrated.relative(rows, ["fitness", "observable"])
    assert np.allclose(rel[:, f["fitness"]], [0.9, 0.9, 0.0, 0.9])
    assert np.allclose(rel[:, f["observable"]], [0.9, 0.9, 0.0, 0.9])
    assert np.array_equal(rel[:, f["in_view"]], rows[:, f["in_view"]])  # the rest as they were
    p, plain = (calibrated.probability(rows, "good_start", str(q)) for q in (path, plain_path))
    assert p[0] == pytest.approx(p[1]) and p[1] > plain[1] and p[3] == plain[3] < p[1], (p, plain)
    assert calibrated.weighs(("in_view", "observable_rel"), "good_start", str(path))
    assert calibrated.anchored_below(str(path)) == 0.03 and calibrated.anchored_below(str(plain_path)) == 0.0
    for bad_spec, bad_models, what in (({**spec, "shares": ["pinned"]}, models, "shares"), (spec, m, "_relative"),
                                       ({**spec, "held_pinned": 1.0}, models, "held")):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({**doc, "models": bad_models, "relative": bad_spec}))
        with pytest.raises(VerdictModelError, match=what):
            calibrated.load(str(bad))
        calibrated.load.cache_clear()


def test_the_floor_alone_measures_anchored_far_only_under_it(tmp_path, monkeypatch):
    """A file whose only reader of ``anchored_far`` is the floor on ``pinned``: the verdict measures it only for a pose
    pinned less than the floor, with the same probability as when it is always measured."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.polish import prepare_polish_cloud

    doc = json.loads(calibrated.DEFAULT_PATH.read_text())
    path = tmp_path / "floor.json"
    path.write_text(json.dumps({**doc, "min_pinned": 0.5, "min_anchored_far": 0.5}))
    monkeypatch.setattr(calibrated, "DEFAULT_PATH", path)
    calibrated.load.cache_clear()
    rng = np.random.default_rng(5)
    walls = np.c_[rng.uniform(-40, 40, 4000), np.where(rng.random(4000) < 0.5, -2.0, 2.0), rng.uniform(-1, 2, 4000)]
    floor = np.c_[rng.uniform(-40, 40, 2000), rng.uniform(-2, 2, 2000), np.full(2000, -1.0)]
    corridor = np.vstack([walls, floor])  # nothing along x: pinned 0.009, anchored_far 0.17
    rc = Config().registration
    target = prepare_polish_cloud(corridor, rc.polish_voxel, rc.polish_neighbors, threads=1)
    from deepbbs_ros.core import anchoring

    calls, held = [], []
    real, real_held = visibility.pose_features, anchoring.anchored
    monkeypatch.setattr(visibility, "pose_features", lambda *a, **k: calls.append(a[5:6]) or real(*a, **k))
    monkeypatch.setattr(anchoring, "anchored", lambda *a, **k: held.append(1) or real_held(*a, **k))
    try:
        assert not calibrated.weighs(("anchored", "anchored_far"), "good_start", floor=False)
        p = verdict.probability(corridor[::10], np.eye(4), target, rc.verdict_dist, "good_start")
        # one pass, the floor as its bound; anchored_far measured (once) for this pose under the floor: vetoed
        assert calls == [(0.5,)] and held == [1] and p == 0.0
        monkeypatch.setattr(visibility, "pose_features", real)
        eager = calibrated.probability(real(corridor[::10], np.eye(4), target, rc.verdict_dist), "good_start")
        assert p == eager
    finally:
        calibrated.load.cache_clear()


def test_the_calibration_writes_a_file_the_verdict_reads(tmp_path):
    """scripts/calibrate_verdict.py on dumped rows (--rows): the plain and the _relative models with their bounds, or
    the plain ones alone (--relative with no share), each a file core/calibrated.py loads."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    import calibrate_verdict as cv

    rng = np.random.default_rng(1)
    n, k = 120, len(visibility.FEATURES)
    y = (rng.random(n) < 0.4).astype(int)
    x = np.clip(rng.uniform(0.2, 0.8, (n, k)) + 0.15 * y[:, None], 0.0, 1.0)
    rows = tmp_path / "rows.npz"
    np.savez(rows, pair=x, good=x, y=y, rig=np.zeros(n, int), kind=np.array(["near"] * n))
    for extra, relative in (([], True), (["--relative"], False)):
        out = tmp_path / f"fit{len(extra)}.json"
        assert cv.main(["--rows", str(rows), "--out", str(out), *extra]) == 0
        doc = json.loads(out.read_text())
        assert ("relative" in doc) == relative and ("good_start_relative" in calibrated.load(str(out))) == relative
        if relative:
            assert doc["relative"]["held_pinned"] == cv.HELD_BOUNDS[0]
            assert calibrated.anchored_below(str(out)) == cv.HELD_BOUNDS[0]


def test_the_benchmark_counts_a_pose_the_second_minimum_turns_away_as_rejected():
    """scripts/benchmarks/verdict.py's counts follow the registration's pair verdict: a pose with the probability but
    a second minimum as good (``veto``) is rejected, counted apart as vetoed; the reliability curve reads the
    probability alone."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
    import verdict as bench

    y = np.array([True, True, False, False])
    prob = np.array([0.95, 0.9, 0.92, 0.1])
    err = np.array([[0.1, 0.05], [0.2, 0.1], [3.0, 1.2], [10.0, 4.0]])
    plain = bench.summary(y, prob, prob, 0.35, 0.7, err=err)
    vetoed = bench.summary(y, prob, prob, 0.35, 0.7, err=err, veto=np.array([False, True, True, False]))
    assert (plain["wrong_accepted"], plain["right_rejected"]) == (1, 0)
    assert (vetoed["wrong_accepted"], vetoed["right_rejected"]) == (0, 1)
    assert vetoed["vetoed"] == {"right": 1, "wrong": 1}
    assert vetoed["classes"]["wrong_accepted"] == 0 and vetoed["classes"]["right_rejected"] == 1
    assert vetoed["reliability"] == plain["reliability"]


def test_the_benchmark_counts_the_good_start_with_and_without_the_second_minimum_check():
    """scripts/benchmarks/verdict.py's ``good_start_checks``: the good start's counts on the same poses with no
    second-minimum check, with it only where the pose can slide (``pinned`` and ``anchored_far`` under the shipped
    coefficients' bound for held poses, 0.02 and 0.1) and on every pose taken."""
    import sys
    from pathlib import Path

    from deepbbs_ros.core.visibility import FEATURES

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts" / "benchmarks"))
    import verdict as bench

    rows = np.ones((4, len(FEATURES)))
    pin, far = FEATURES.index("pinned"), FEATURES.index("anchored_far")
    rows[:, pin] = [0.01, 0.01, 0.01, 0.3]
    rows[:, far] = [0.05, 0.05, 0.2, 1.0]
    free = np.array([bench.slides(r) for r in rows])
    assert free.tolist() == [True, True, False, False]  # held: anchored_far 0.2 or pinned 0.3
    y = np.array([True, False, False, False])
    prob = np.array([0.9, 0.95, 0.8, 0.99])
    err = np.array([[0.1, 0.05], [3.0, 0.2], [2.5, 0.1], [0.2, 0.6]])
    amb = np.array([False, True, True, False])
    out = bench.checks(y, prob, 0.7, amb, free, err, rows)
    assert (out["taken"], out["taken_sliding"]) == (4, 2)
    assert out["none"] == {"wrong_accepted": 3, "right_rejected": 0}
    assert out["slides"] == {"wrong_accepted": 2, "right_rejected": 0}
    assert out["all"] == {"wrong_accepted": 1, "right_rejected": 0}
    # looser than 5 tolerances (pinned under 1 / (1 + 5^2)), or than 2 (under 0.2) when not sure (under 0.95):
    # registration.good_start_second_minimum checks the first three (pinned 0.01: 9.9 tolerances), not the last
    assert out["taken_loose"] == 3 and out["loose"] == {"wrong_accepted": 1, "right_rejected": 0}
    sure = bench.checks(y, prob, 0.7, amb, free, err, np.where(np.arange(len(FEATURES)) == pin, 0.1, rows), 0.95)
    assert sure["taken_loose"] == 2 and sure["loose"]["wrong_accepted"] == 2  # 3 tolerances: the sure one unchecked
    assert out["found"] == [[False, 3.0, 0.2, 0.95, 0.01, 0.05], [False, 2.5, 0.1, 0.8, 0.01, 0.2]]
