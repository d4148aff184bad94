"""train.sp_weight (L2-SP, deepbbs_ros/train/anchor.py): alpha / 2 ||w - w_start||^2 added to each step's loss, on a
tiny model in seconds: zero at the start weights, the known value and gradient at a known offset, and the start kept
through a resume."""

from __future__ import annotations

import pytest
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.train.anchor import anchor_of, sp_distance2
from deepbbs_ros.train.trainer import Trainer
from tests.test_train import synthetic_drive, tiny_config

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _weights(model) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.parameters()]


def test_penalty_is_zero_at_the_start_and_known_at_an_offset():
    model = DeepBBSNet(tiny_config().model)
    anchor = anchor_of(model)
    assert float(sp_distance2(model, anchor).detach()) == 0.0
    n = sum(p.numel() for p in model.parameters())
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.01)
    d2 = sp_distance2(model, anchor)
    assert float(d2.detach()) == pytest.approx(n * 1e-4, rel=1e-4)
    (0.5 * 3.0 * d2).backward()  # alpha = 3: the gradient is alpha (w - w_start) = 0.03 everywhere
    for p in model.parameters():
        assert torch.allclose(p.grad, torch.full_like(p, 0.03), rtol=1e-3)
    assert Config().train.sp_weight == 0.0  # off by default
    with pytest.raises(ValueError):
        Config().replace(**{"train.sp_weight": -1.0}).validate()


def test_first_step_is_unchanged_and_later_steps_are_held(tmp_path):
    """At the start weights the term and its gradient are 0: the first step is the plain step. A strong alpha then
    holds the weights nearer the start than the plain run."""
    drives = [synthetic_drive(frames=6)]
    plain = Trainer(tiny_config(), tmp_path / "a", drives, progress=False, curves=False)
    held = Trainer(tiny_config(**{"train.sp_weight": 1e4}), tmp_path / "b", drives, progress=False, curves=False)
    start = _weights(held.model)
    assert plain.sp_anchor is None
    a, b = plain.train_step(), held.train_step()
    assert b["loss"] == pytest.approx(a["loss"], rel=1e-6) and b["sp_dist"] == 0.0
    assert all(torch.equal(x, y) for x, y in zip(_weights(plain.model), _weights(held.model)))
    for _ in range(4):
        a, b = plain.train_step(), held.train_step()

    def dist(tr) -> float:
        return sum(float(((w - s) ** 2).sum()) for w, s in zip(_weights(tr.model), start)) ** 0.5
    assert b["sp_dist"] > 0 and dist(held) < 0.5 * dist(plain)


def test_resume_keeps_the_start_weights(tmp_path):
    """2 + 2 steps with a resume into a trainer built from other weights == 4 steps straight: the start the term
    pulls towards is the saved one, not the weights the resuming trainer was built with."""
    cfg = tiny_config(**{"train.sp_weight": 50.0})
    drives = [synthetic_drive(frames=6)]
    straight = Trainer(cfg, tmp_path / "a", drives, progress=False, curves=False)
    straight.fit(max_steps=4)
    Trainer(cfg, tmp_path / "b", drives, progress=False, curves=False).fit(max_steps=2)
    other = DeepBBSNet(cfg.model)
    with torch.no_grad():
        for p in other.parameters():
            p.add_(0.5)
    second = Trainer(cfg, tmp_path / "b", drives, progress=False, curves=False, model=other)
    assert second.resume() == 2
    second.fit(max_steps=2)
    assert all(torch.equal(x, y) for x, y in zip(_weights(straight.model), _weights(second.model)))


def test_script_runs_the_mix_schedule_with_the_pull_to_the_shipped_weights(tmp_path):
    """scripts/train_mix_sp.sh (dry run): scripts/train_mix_clean.sh's data, every pair, the mix schedule, validated
    on the mix and the road folders, and train.sp_weight; it starts from the shipped weights without a state."""
    import json
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {"PATH": "/usr/bin:/bin", "PY": "echo", "RUN": str(tmp_path / "run"), "CACHE": str(tmp_path / "c"),
           "DRIVES": "4", "NAME": "no_such_state"}
    out = subprocess.run(["sh", str(root / "scripts" / "train_mix_sp.sh")], env=env, capture_output=True, text=True,
                         check=True).stdout
    mix = [line for line in out.splitlines() if f"--out {tmp_path / 'c'}/mixclean_train" in line]
    assert len(mix) == 2 and all("--sweeps compensated" in line for line in mix)
    (fit,) = [line for line in out.splitlines() if " fit " in line]
    assert "--init shipped" in fit and fit.count("--val-cache") == 2
    sets = dict(item.split()[0].split("=", 1) for item in fit.split("--set ")[1:])
    assert sets.pop("train.sp_weight") == "0.4" and sets.pop("train.hard_pair_deg") == "0"
    for key in ("train.checkpoint_minutes", "train.val_every", "train.val_pairs"):
        sets.pop(key)
    schedule = subprocess.run(["sh", "-c", ". scripts/train_mix_data.sh; echo $MIX_SCHEDULE"], cwd=root,
                              capture_output=True, text=True, check=True).stdout
    assert sets == dict(item.split()[0].split("=", 1) for item in schedule.split("--set ")[1:])
    cfg = Config().replace(**{k: v if k == "train.pair_balance" else json.loads(v) for k, v in sets.items()})
    assert cfg.validate().train.num_points == 512
    # the committed state resumes (the shipped weights it is held to are in it)
    committed = subprocess.run(["sh", str(root / "scripts" / "train_mix_sp.sh")], env={**env, "NAME": "mix_sp"},
                               capture_output=True, text=True, check=True).stdout
    assert "--resume deepbbs_ros/models/train_state/mix_sp/state_latest.pt" in committed
    state = torch.load(root / "deepbbs_ros/models/train_state/mix_sp/state_latest.pt", weights_only=False)
    shipped = torch.load(root / "deepbbs_ros/models/deepbbspp_lidar.pt", weights_only=False)["state_dict"]
    assert state["sp_anchor"].keys() <= shipped.keys()
    assert all(torch.equal(v, shipped[k]) for k, v in state["sp_anchor"].items())
