"""scripts/train_mix.sh, train_mix_keep.sh and train_mix_span.sh (both train_mix_balanced.sh): their cache and fit
settings are valid, in seconds
(one short drive, two steps of a tiny model), the validation reports each validation folder apart, and a slow mount's
frames are spread over the travel asked for (``--min-span``)."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.train.cache import load_cache, load_drive, save_drive
from deepbbs_ros.train.sim_cache import SimDriveSpec, simulate_cached_drive
from deepbbs_ros.train.trainer import Trainer
from tests.test_train import TINY, synthetic_drive

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "train_mix.sh"
KEEP = SCRIPT.with_name("train_mix_keep.sh")
SPAN = SCRIPT.with_name("train_mix_span.sh")
DATA = SCRIPT.with_name("train_mix_data.sh")


def _script(path: Path = SCRIPT) -> str:
    return path.read_text()


def _var(name: str) -> str:
    m = re.search(rf"^{name}=(\S+)$", _script(DATA), re.M)
    assert m, name
    return m.group(1)


def _run(script: Path, tmp_path: Path, **env: str) -> str:
    """What ``script`` runs (its commands echoed: PY=echo), with its run and cache folders under ``tmp_path``."""
    env = {"PATH": "/usr/bin:/bin", "PY": "echo", "RUN": str(tmp_path / "run"), "CACHE": str(tmp_path / "c"),
           "DRIVES": "4", **env}
    return subprocess.run(["sh", str(script)], env=env, capture_output=True, text=True, check=True).stdout


def _fit_sets(out: str) -> dict[str, str]:
    """The ``--set train.*`` of the one fit command in a script's echoed commands."""
    fit = [line for line in out.splitlines() if " fit " in line]
    assert len(fit) == 1, out
    return dict(re.findall(r"--set (train\.\w+)=(\S+)", fit[0]))


@pytest.fixture(autouse=True)
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.mark.parametrize("script", [SCRIPT, KEEP, SPAN], ids=["train_mix", "train_mix_keep", "train_mix_span"])
def test_schedule_is_a_valid_config(script, tmp_path):
    out = _run(script, tmp_path)
    sets = _fit_sets(out)
    assert {"train.epochs", "train.lr", "train.val_pairs", "train.num_points"} <= set(sets)
    cfg = Config().replace(**{k: v if k == "train.pair_balance" else json.loads(v) for k, v in sets.items()})
    cfg = cfg.validate()
    assert cfg.train.num_points == 512 and cfg.train.epochs * cfg.train.steps_per_epoch > 0
    # every run's data is the one data step's (the same sensor, mount and place draws)
    mix = [line for line in out.splitlines() if " cache " in line and "--sensors " + _var("SENSORS") in line]
    assert len(mix) == 2 and all("--mounts " + _var("MOUNTS") in line for line in mix)
    if script in (KEEP, SPAN):  # pairs drawn uniform in distance
        assert cfg.train.pair_balance == "distance"
        assert f"--run {tmp_path / 'run'}" in out
    if script == SPAN:  # the second run's schedule; only the frames' spread differs
        assert sets == _fit_sets(_run(KEEP, tmp_path)) and all("--min-span 10" in line for line in mix)
    if script == KEEP:
        assert "--min-span" not in out and all(f"--out {tmp_path / 'c'}/mix_train" in line for line in mix)


def test_mix_cache_command_on_one_short_drive(tmp_path):
    from deepbbs_ros.cli.train import main

    out = tmp_path / "mix"
    assert main(["cache", "--out", str(out), "--split", "train", "--seeds", "20005:20006", "--frames", "2",
                 "--cache-points", "256", "--scenes", _var("SCENES"), "--sensors", _var("SENSORS"), "--mounts",
                 _var("MOUNTS"), "--no-progress", "--threads", "1"]) == 0
    (drive,) = load_cache(out)
    assert len(drive) == 2 and drive.has_gt and drive.meta["cache"] == "mix"
    assert drive.scene == _var("SCENES").split(",")[0]


def test_randomised_road_sensor_on_a_car_off_the_road(tmp_path):
    """'random' sensor on a car in a courtyard: the rig simulator, not the road drive (which has no courtyard)."""
    path = simulate_cached_drive(SimDriveSpec("courtyard", 20006, 2), tmp_path, Config().preprocess, 256)
    d = load_drive(path)
    assert len(d) == 2 and d.meta["sensor"]["mount"] == "car" and d.frame(0).shape[0] > 50


class _Walk:
    """A simulator's poses only: straight ahead at ``step`` m per sweep."""

    def __init__(self, step: float):
        self.step = step

    def pose_at(self, k: int) -> np.ndarray:
        T = np.eye(4)
        T[0, 3] = self.step * k
        return T


def test_frame_stride_spans_the_travel_asked_for():
    from deepbbs_ros.train.sim_cache import MAX_FRAME_STRIDE, frame_stride

    assert frame_stride(_Walk(0.1), 5, 0.0) == 1  # off: consecutive sweeps
    assert frame_stride(_Walk(0.1), 5, 2.0) == 5  # 4 gaps of 5 sweeps of 0.1 m: 2 m
    assert frame_stride(_Walk(0.1), 5, 1.9) == 5 and frame_stride(_Walk(0.1), 5, 2.01) == 6
    assert frame_stride(_Walk(1.0), 5, 2.0) == 1  # a fast car already travels that far
    assert frame_stride(_Walk(0.001), 5, 2.0) == MAX_FRAME_STRIDE  # standing still: at most 1 s apart


def test_a_handheld_drive_spread_over_its_span(tmp_path):
    """--min-span on a handheld walk (0.5-1.2 m/s): frames several sweeps apart, travelling the span asked for,
    each with the ground truth of its own sweep."""
    from deepbbs_ros.sim.rig import make_simulator
    from deepbbs_ros.train.sim_cache import MAX_FRAME_STRIDE

    spec = SimDriveSpec("corridor", 20006, 3, sensor="vlp16", mount="handheld", min_span=2.0)
    d = load_drive(simulate_cached_drive(spec, tmp_path, Config().preprocess, 256))
    stride = d.meta["sensor"]["frame_stride"]
    pos = d.T_world_lidar[:, :3, 3]
    assert len(d) == 3 and 1 < stride <= MAX_FRAME_STRIDE
    assert np.linalg.norm(np.diff(pos, axis=0), axis=1).sum() >= 2.0 * 0.9  # path length; chord a little shorter
    assert np.diff(d.stamps_ns)[0] == stride * 100_000_000  # 10 Hz sweeps, every stride-th kept
    sim = make_simulator("corridor", 20006, "vlp16", "handheld", frames=3 * MAX_FRAME_STRIDE)
    for k in range(3):  # the pose of the sweep the frame is
        np.testing.assert_allclose(d.T_world_lidar[k], sim.pose_at(k * stride), atol=1e-9)


def test_fit_validates_each_folder_apart(tmp_path):
    sets = {k: json.loads(v) for k, v in _fit_sets(_run(SCRIPT, tmp_path / "echo")).items()}
    cfg = Config().replace(**{**sets, **TINY, "train.num_points": 0, "train.epochs": 1, "train.val_every": 1,
                              "train.val_pairs": 4})
    val = {}
    for folder, seed in (("mix_val", 5), ("worlds_val", 9)):
        d = synthetic_drive(f"urban_{seed}", 12, seed=seed)
        save_drive(tmp_path / folder / f"{d.name}.npz", [d.frame(i) for i in range(len(d))], d.T_world_lidar,
                   d.stamps_ns, d.meta)
        val[folder] = tmp_path / folder
    tr = Trainer(cfg, tmp_path / "run", [synthetic_drive(frames=6)], load_cache(list(val.values())),
                 progress=False, curves=False)
    res = tr.fit(max_steps=2)
    rec = res["best_val"]
    assert tr.step == 2 and set(rec["groups"]) == {"mix_val", "worlds_val"}
    for g in rec["groups"].values():
        assert g["plain"]["n"] == 2 and g["yaw"]["n"] == 2
    mean = np.mean([g[s]["success"] for g in rec["groups"].values() for s in ("plain", "yaw")]) * 2
    assert Trainer.score(rec)[0] == pytest.approx(mean)


def test_evaluate_on_a_rig():
    """deepbbs-train evaluate --rigs: a handheld Livox in a courtyard is a "scene" of the report; a malformed
    rig is a one-line error."""
    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.errors import ConfigError
    from deepbbs_ros.train.evaluate import evaluate

    cfg = Config().replace(**{**TINY, "preprocess.num_points": 128})
    torch.manual_seed(0)
    report = evaluate(cfg, model=DeepBBSNet(cfg.model), rigs=["avia:handheld:courtyard"], drives_per_scene=1,
                      frames=12, stride=10, yaw_deg=0.0, methods=["deepbbs", "gicp-gt"], progress=False)
    s = report["summary"]["plain"]["gicp-gt"]
    assert s["avia:handheld:courtyard"]["pairs"] == s["all"]["pairs"] >= 1
    assert s["all"]["success"] == 1.0  # GICP from the truth stays there: the rig's ground truth is right
    assert report["protocol"]["sensor"].startswith("the rigs")
    with pytest.raises(ConfigError, match="sensor:mount:place"):
        evaluate(cfg, model=DeepBBSNet(cfg.model), rigs=["avia:handheld"], drives_per_scene=1, frames=12,
                 progress=False)


def test_evaluate_network_alone_runs_no_search(registration_configs):
    """evaluate's "deepbbs" (the network alone) and "refine-only" run without the global search, whose other
    starts go through GICP; "deepbbs++" keeps the configured search."""
    from deepbbs_ros.core.model import DeepBBSNet
    from deepbbs_ros.train.evaluate import evaluate

    cfg = Config().replace(**{**TINY, "preprocess.num_points": 128})
    torch.manual_seed(0)
    evaluate(cfg, model=DeepBBSNet(cfg.model), rigs=["vlp16:wheeled:courtyard"], drives_per_scene=1, frames=2,
             stride=10, yaw_deg=0.0, methods=["deepbbs++", "deepbbs", "refine-only"], progress=False)
    assert [c.registration.global_search for c in registration_configs] == ["auto", "off", "off"]


def test_bounded_run_is_the_third_run_with_its_loss_and_folders(tmp_path):
    """NAME=mix_bound POSE_LOSS=bounded scripts/train_mix_span.sh: the third run's data and schedule, the bounded
    per-pair pose loss, its own run and state folders."""
    out = _run(SPAN, tmp_path, NAME="mix_bound", POSE_LOSS="bounded")
    assert "--min-span 10" in out
    sets = _fit_sets(out)
    assert sets.pop("train.pose_loss") == "bounded" and sets == _fit_sets(_run(KEEP, tmp_path))
    assert f"--run {tmp_path / 'run'}" in out
    assert Config().replace(**{"train.pose_loss": "bounded"}).validate().train.pose_loss == "bounded"
    with pytest.raises(ValueError):
        Config().replace(**{"train.pose_loss": "huber"}).validate()


def test_mix_data_step_commands():
    """The data step sourced by the three runs: the mix drives (two halves of the seeds) with the run's own cache
    options, the mix validation drives, the HDL-64E road folders without them."""
    out = subprocess.run(["sh", "-c", ". scripts/train_mix_data.sh; T=echo CACHE=c DRIVES=4; "
                          "mix_data mix_span --min-span 10"], cwd=DATA.parents[1], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert len(out) == 6, out
    train = [line for line in out if "--out c/mix_span_train" in line]
    # the halves run in the background (echo's lines in either order)
    assert sorted(line.split("--seeds ")[1].split()[0] for line in train) == ["20000:20002", "20002:20004"]
    assert all("--min-span 10" in line for line in train + [line for line in out if "c/mix_span_val" in line])
    assert not any("--min-span" in line for line in out if "worlds_" in line)
