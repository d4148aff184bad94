"""Device choice: CUDA when present, else CPU; never hard-coded."""

from __future__ import annotations

from deepbbs_ros.errors import ConfigError


def resolve_device(name: str = "auto"):
    """``"auto"`` -> ``cuda`` if available else ``cpu``; ``"cuda"``/``"cuda:N"`` must exist."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ConfigError(f"registration.device: {name!r} requested but CUDA is not available")
        dev = torch.device(name)
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"registration.device: {name!r} does not exist ({torch.cuda.device_count()} GPU(s))")
        return dev
    raise ConfigError(f"registration.device: unknown device {name!r} (use auto, cpu, cuda or cuda:N)")
