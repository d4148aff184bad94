"""Checkpoints: the weights, the whole :class:`~deepbbs_ros.config.Config` and training metadata.

File layout (``torch.save`` of plain types only, so it loads with ``weights_only=True``)::

    {
        "format": "deepbbs_ros.checkpoint",
        "version": 1,
        "state_dict": {name: tensor, ...},        # DeepBBSNet weights (CPU tensors)
        "config": Config.to_dict(),               # model section builds the network; preprocess
                                                  # section is what the model was trained on
        "metadata": {...},                        # training metadata (epochs, data, metrics, ...)
    }

Loadable on any device (``map_location``). Missing, corrupt or mismatched files raise
:class:`~deepbbs_ros.errors.ModelError` with a one-line message naming the path.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError, ModelError

__all__ = ["FORMAT", "VERSION", "default_weights_path", "save_checkpoint", "load_checkpoint"]

FORMAT = "deepbbs_ros.checkpoint"
VERSION = 1


def default_weights_path() -> Path:
    """The model shipped with the package: ``deepbbs_ros/models/deepbbspp_lidar.pt``."""
    return Path(__file__).resolve().parents[1] / "models" / "deepbbspp_lidar.pt"


def _plain(value: Any, key: str) -> Any:
    """Metadata as plain types (numpy scalars/arrays -> Python), tensors kept on the CPU."""
    import numpy as np

    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _plain(v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{key}[{i}]") for i, v in enumerate(value)]
    raise ModelError(f"checkpoint metadata {key} has unsupported type {type(value).__name__}")


def save_checkpoint(path: str | Path, model: torch.nn.Module, config: Config, metadata: dict | None = None) -> Path:
    """Write ``model``'s weights with ``config`` (its ``model`` section must describe ``model``).

    Args:
        path: output file (parent folders are created); written atomically (tmp file + rename).
        model: a :class:`~deepbbs_ros.core.model.DeepBBSNet`.
        config: the whole configuration (``config.model`` is replaced by ``model.cfg`` if it has one).
        metadata: plain types, numpy values or tensors (e.g. epoch, metrics, optimizer state).
    Returns:
        the path written.
    """
    path = Path(path)
    cfg = config.to_dict()
    model_cfg = getattr(model, "cfg", None)
    if model_cfg is not None:
        import dataclasses

        cfg["model"] = dataclasses.asdict(model_cfg)
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "config": cfg,
        "metadata": _plain(dict(metadata or {}), "metadata"),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    try:
        torch.save(payload, tmp)
        tmp.replace(path)
    except OSError as err:
        raise ModelError(f"cannot write checkpoint {path}: {err}") from err
    return path


def _current_keys(data: object) -> object:
    """A checkpoint's config without the keys that later versions retired, outside the ``model`` section.

    Only ``model`` describes the weights (strict: an unknown key there is an error); the other
    sections record how the run was configured, and a renamed registration or node option must not
    make older weights unloadable.
    """
    import dataclasses

    if not isinstance(data, dict):
        return data
    known = {f.name: {g.name for g in dataclasses.fields(f.type if isinstance(f.type, type) else
                                                          type(getattr(Config(), f.name)))}
             for f in dataclasses.fields(Config)}
    return {sec: ({k: v for k, v in vals.items() if k in known[sec]}
                  if sec != "model" and sec in known and isinstance(vals, dict) else vals)
            for sec, vals in data.items()}


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu"):
    """Read a checkpoint and build the model on ``device`` (eval mode).

    Returns:
        (model: DeepBBSNet, config: Config, metadata: dict)
    Raises:
        ModelError: file missing, unreadable/corrupt, not a deepbbs_ros checkpoint, invalid config,
            or weights that do not match the configured architecture.
    """
    from deepbbs_ros.core.model import DeepBBSNet

    path = Path(path)
    if not path.is_file():
        raise ModelError(f"model file not found: {path} (train one with deepbbs-train)")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # torch raises many types for corrupt files
        msg = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ModelError(f"corrupt or unreadable checkpoint {path}: {msg}") from err
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ModelError(f"{path} is not a deepbbs_ros checkpoint (no format tag {FORMAT!r})")
    if payload.get("version") != VERSION:
        raise ModelError(f"{path}: unsupported checkpoint version {payload.get('version')!r} (expected {VERSION})")
    try:
        config = Config.from_dict(_current_keys(payload.get("config")))
    except ConfigError as err:
        raise ModelError(f"{path}: invalid config in checkpoint: {err}") from err
    model = DeepBBSNet(config.model)
    state = payload.get("state_dict")
    if not isinstance(state, dict):
        raise ModelError(f"{path}: checkpoint has no state_dict")
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    shapes = [k for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k].shape)]
    if missing or unexpected or shapes:
        parts = []
        for name, keys in (("missing", missing), ("unexpected", unexpected), ("wrong shape", shapes)):
            if keys:
                parts.append(f"{len(keys)} {name} (e.g. {keys[0]})")
        raise ModelError(f"{path}: weights do not match the model config: {', '.join(parts)}")
    model.load_state_dict(state, strict=True)
    model.to(device).eval()
    return model, config, dict(payload.get("metadata") or {})
