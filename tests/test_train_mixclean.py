"""scripts/train_mix_clean.sh: mix sweeps compensated to their stamps (``--sweeps compensated``) and the pairs the
network's pass leaves far off left out of the loss (``train.hard_pair_deg``), on pairs of known error, in seconds."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from deepbbs_ros.config import Config
from deepbbs_ros.core.model import NetOutput
from deepbbs_ros.errors import DatasetError
from deepbbs_ros.train.cache import load_drive
from deepbbs_ros.train.loss import deepbbs_loss, loss_options
from deepbbs_ros.train.sim_cache import SimDriveSpec, sim_drive_specs, simulate_cached_drive
from deepbbs_ros.train.trainer import Trainer
from tests.test_train import synthetic_drive, tiny_config

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "train_mix_clean.sh"
pytestmark = pytest.mark.usefixtures("torch_one_thread")


def _yaw(deg: float) -> torch.Tensor:
    a = np.radians(deg)
    return torch.tensor([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]],
                        dtype=torch.float64)


def _batch(degs: list[float], requires_grad: bool = False):
    """A batch whose pair k the network got ``degs[k]`` deg off in yaw and 0.1 m off in x (ground truth: identity)."""
    g = torch.Generator().manual_seed(2)
    src = torch.randn(len(degs), 30, 3, generator=g, dtype=torch.float64) * 10
    R = torch.stack([_yaw(d) for d in degs]).requires_grad_(requires_grad)
    t = torch.tensor([[0.1, 0.0, 0.0]] * len(degs), dtype=torch.float64)
    out = NetOutput(R, t, src.clone(), torch.ones(len(degs), 30), torch.ones(len(degs)))
    return out, src, src.clone(), torch.eye(3, dtype=torch.float64).expand(len(degs), 3, 3), \
        torch.zeros(len(degs), 3, dtype=torch.float64)


def test_hard_pairs_are_left_out_of_the_loss():
    opts = {"scale": 0.025, "theta": 0.5, "corr_weight": 1.0, "trans_weight": 5.0}
    alone = deepbbs_loss(*_batch([2.0]), **opts)
    for hard in (0.0, 10.0):
        out, *rest = _batch([2.0, 30.0, 11.0], requires_grad=True)
        terms = deepbbs_loss(out, *rest, **opts, hard_pair_deg=hard)
        terms.total.backward()
        grad = out.R.grad.abs().sum(dim=(1, 2))
        if hard == 0:  # every pair in the mean
            assert float(terms.kept) == 1.0 and bool((grad > 0).all())
            assert float(terms.total.detach()) > 10 * float(alone.total)
        else:  # only the 2 deg pair: its own loss, no pull from the 30 and 11 deg ones
            assert float(terms.kept) == pytest.approx(1 / 3)
            assert float(terms.total.detach()) == pytest.approx(float(alone.total), rel=1e-6)
            assert float(grad[0]) > 0 and float(grad[1]) == 0.0 and float(grad[2]) == 0.0
        # the logged terms still describe every pair
        assert float(terms.rot) == pytest.approx(np.mean([4 * (1 - np.cos(np.radians(d))) for d in (2, 30, 11)]),
                                                 rel=1e-5)
    none_left = deepbbs_loss(*_batch([30.0, 40.0]), **opts, hard_pair_deg=10.0)
    assert float(none_left.total) == 0.0 and float(none_left.kept) == 0.0
    assert loss_options(Config(), 0)["hard_pair_deg"] == 0.0  # the default: every pair counts
    assert loss_options(Config().replace(**{"train.hard_pair_deg": 10.0}), 0)["hard_pair_deg"] == 10.0
    with pytest.raises(ValueError):
        Config().replace(**{"train.hard_pair_deg": -1.0}).validate()


def test_a_training_step_logs_the_share_kept(tmp_path):
    """A tiny model's step with the bound: the share of pairs kept is logged; a 0.001 deg bound keeps none of a
    fresh model's pairs, and the step leaves the weights where they were."""
    drives = [synthetic_drive(frames=4)]
    tr = Trainer(tiny_config(**{"train.hard_pair_deg": 90.0}), tmp_path / "a", drives, progress=False, curves=False)
    rec = tr.train_step()
    assert 0.0 <= rec["kept"] <= 1.0 and np.isfinite(rec["loss"])
    tr = Trainer(tiny_config(**{"train.hard_pair_deg": 0.001}), tmp_path / "b", drives, progress=False, curves=False)
    before = [p.detach().clone() for p in tr.model.parameters()]
    rec = tr.train_step()
    assert rec["kept"] == 0.0 and rec["loss"] == 0.0
    assert all(torch.equal(a, b.detach()) for a, b in zip(before, tr.model.parameters()))


def test_compensated_sweeps_keep_the_seed_s_drive(tmp_path):
    """--sweeps compensated: a handheld drive whose seed draws raw sweeps is simulated with the same sensor and path,
    its sweeps compensated to their stamps."""
    mixed = SimDriveSpec("corridor", 20001, 2, sensor="vlp16", mount="handheld")  # this seed draws raw sweeps
    comp = SimDriveSpec("corridor", 20001, 2, sensor="vlp16", mount="handheld", sweeps="compensated")
    a = load_drive(simulate_cached_drive(mixed, tmp_path / "mixed", Config().preprocess, 256))
    b = load_drive(simulate_cached_drive(comp, tmp_path / "comp", Config().preprocess, 256))
    assert a.meta["motion_distortion"] and not a.meta["compensated"]
    assert b.meta["motion_distortion"] and b.meta["compensated"]
    assert a.meta["sensor"] == b.meta["sensor"]
    np.testing.assert_array_equal(a.T_world_lidar, b.T_world_lidar)
    assert not np.array_equal(a.points, b.points)
    assert all(s.sweeps == "compensated" for s in sim_drive_specs(["hall"], [20000, 20001], 2, sweeps="compensated"))
    with pytest.raises(DatasetError):
        sim_drive_specs(["hall"], [20000], 2, sweeps="deskewed")


def test_script_runs_the_mix_schedule_on_compensated_mix_drives(tmp_path):
    env = {"PATH": "/usr/bin:/bin", "PY": "echo", "RUN": str(tmp_path / "run"), "CACHE": str(tmp_path / "c"),
           "DRIVES": "4"}
    out = subprocess.run(["sh", str(SCRIPT)], env=env, capture_output=True, text=True, check=True).stdout
    mix = [line for line in out.splitlines() if f"--out {tmp_path / 'c'}/mixclean_train" in line]
    assert len(mix) == 2 and all("--sweeps compensated" in line for line in mix)
    assert sorted(line.split("--seeds ")[1].split()[0] for line in mix) == ["20000:20002", "20002:20004"]
    roads = [line for line in out.splitlines() if "worlds_train --split" in line]
    assert len(roads) == 2 and not any("--sweeps" in line for line in roads)
    (fit,) = [line for line in out.splitlines() if " fit " in line]
    sets = dict(item.split("=", 1) for item in fit.split("--set ")[1:] for item in [item.split()[0]])
    assert sets.pop("train.hard_pair_deg") == "10" and sets.pop("train.checkpoint_minutes") == "0"
    control = subprocess.run(["sh", "-c", ". scripts/train_mix_data.sh; echo $MIX_SCHEDULE"], cwd=SCRIPT.parents[1],
                             capture_output=True, text=True, check=True).stdout
    assert sets == dict(item.split()[0].split("=", 1) for item in control.split("--set ")[1:])
    cfg = Config().replace(**{k: v if k == "train.pair_balance" else json.loads(v) for k, v in sets.items()})
    assert cfg.validate().train.num_points == 512
    # it resumes the committed state; a new NAME starts from the shipped weights
    assert "--resume deepbbs_ros/models/train_state/mixclean/state_latest.pt" in fit
    fresh = subprocess.run(["sh", str(SCRIPT)], env={**env, "NAME": "no_such_state"}, capture_output=True, text=True,
                           check=True).stdout
    assert "--init shipped" in [line for line in fresh.splitlines() if " fit " in line][0]
