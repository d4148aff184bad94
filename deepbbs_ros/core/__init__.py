"""The DeepBBS++ core: preprocessing, SoftBBS, weighted Procrustes, the network, registration.

No ROS import. See ARCHITECTURE.md. Names are exported lazily so that importing
``deepbbs_ros.core.preprocess`` does not import torch.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "DeepBBSRegistration": "registration",
    "RegistrationResult": "registration",
    "register_pair": "pair",
    "clear_register_pair_cache": "pair",
    "DeepBBSNet": "model",
    "DeepBBSNetwork": "network",
    "NetOutput": "model",
    "weighted_procrustes": "procrustes",
    "save_checkpoint": "checkpoint",
    "load_checkpoint": "checkpoint",
    "default_weights_path": "checkpoint",
    "PreprocessResult": "preprocess",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        module = importlib.import_module(f"{__name__}.{_EXPORTS[name]}")
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
