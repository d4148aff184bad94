"""Checkpoint round trip and the ModelError cases."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from deepbbs_ros.config import Config, ModelConfig
from deepbbs_ros.core.checkpoint import default_weights_path, load_checkpoint, save_checkpoint
from deepbbs_ros.core.model import DeepBBSNet
from deepbbs_ros.errors import ModelError

TINY = ModelConfig(k=6, dgcnn_widths=[8, 8], emb_dims=16, n_heads=2, ff_dims=16)


def _config() -> Config:
    cfg = Config()
    cfg.model = TINY
    cfg.preprocess.num_points = 512
    return cfg


def test_round_trip(tmp_path, rng):
    torch.manual_seed(0)
    model = DeepBBSNet(TINY)
    opt = torch.optim.Adam(model.parameters())
    meta = {"epoch": 3, "val_rot_deg": np.float32(0.25), "history": np.arange(3), "optimizer": opt.state_dict()}
    path = save_checkpoint(tmp_path / "sub" / "m.pt", model, _config(), meta)
    loaded, cfg, meta2 = load_checkpoint(path)
    assert cfg.model == TINY and cfg.preprocess.num_points == 512
    assert meta2["epoch"] == 3 and meta2["history"] == [0, 1, 2] and isinstance(meta2["val_rot_deg"], float)
    assert not loaded.training
    src = torch.tensor(rng.uniform(-10, 10, size=(1, 40, 3)), dtype=torch.float32)
    with torch.inference_mode():
        a, b = model.eval()(src, src + 1), loaded(src, src + 1)
    torch.testing.assert_close(a.R, b.R)
    assert not (tmp_path / "sub" / "m.pt.tmp").exists()


def test_model_config_comes_from_the_model(tmp_path):
    """config.model is replaced by the model's own config, so the file always describes the weights."""
    model = DeepBBSNet(TINY)
    save_checkpoint(tmp_path / "m.pt", model, Config())  # default ModelConfig in the passed config
    loaded, cfg, _ = load_checkpoint(tmp_path / "m.pt")
    assert cfg.model == TINY


def test_missing_file(tmp_path):
    with pytest.raises(ModelError, match=r"model file not found: .*nope\.pt \(train one with deepbbs-train\)"):
        load_checkpoint(tmp_path / "nope.pt")


def test_corrupt_file(tmp_path):
    path = tmp_path / "bad.pt"
    path.write_bytes(b"\x00not a checkpoint" * 10)
    with pytest.raises(ModelError, match=r"corrupt or unreadable checkpoint .*bad\.pt"):
        load_checkpoint(path)


def test_truncated_file(tmp_path):
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(TINY), _config())
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match=r"corrupt or unreadable checkpoint .*m\.pt"):
        load_checkpoint(path)


def _saved_payload(tmp_path) -> tuple:
    """A tiny model saved to ``m.pt``: (path, the payload dict as torch.load reads it back)."""
    path = save_checkpoint(tmp_path / "m.pt", DeepBBSNet(TINY), _config())
    return path, torch.load(path, weights_only=True)


def _assert_load_fails(path, payload, match: str) -> None:
    """Save ``payload`` over ``path``; load_checkpoint must raise ModelError matching ``match``."""
    torch.save(payload, path)
    with pytest.raises(ModelError, match=match):
        load_checkpoint(path)


def test_not_a_deepbbs_checkpoint(tmp_path):
    _assert_load_fails(tmp_path / "other.pt", {"weights": torch.zeros(3)}, r"other\.pt is not a deepbbs_ros checkpoint")


def test_mismatched_weights(tmp_path):
    path, payload = _saved_payload(tmp_path)
    payload["config"]["model"]["emb_dims"] = 32
    _assert_load_fails(path, payload, r"m\.pt: weights do not match the model config: .*wrong shape")
    payload["config"]["model"]["emb_dims"] = 16
    del payload["state_dict"]["temp_head.0.weight"]
    _assert_load_fails(path, payload, r"1 missing \(e\.g\. temp_head\.0\.weight\)")


def test_invalid_config_in_checkpoint(tmp_path):
    path, payload = _saved_payload(tmp_path)
    payload["config"]["model"]["bogus"] = 1
    _assert_load_fails(path, payload, r"invalid config in checkpoint: .*model\.bogus")


def test_default_weights_path():
    path = default_weights_path()
    assert path.name == "deepbbspp_lidar.pt" and path.parent.name == "models"
    assert path.parent.parent.name == "deepbbs_ros"
