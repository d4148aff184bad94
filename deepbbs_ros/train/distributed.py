"""Training on several processes with torch.distributed: ``torchrun --nproc_per_node N deepbbs-train fit ...``.

torchrun sets ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK`` and the rendezvous address for every process it
starts; :func:`init_from_env` joins the process group (NCCL when the process trains on CUDA, gloo on a CPU)
and picks the process's device (``cuda:LOCAL_RANK`` when CUDA is used). A plain ``deepbbs-train fit``
(no ``WORLD_SIZE`` or ``WORLD_SIZE=1``) never touches torch.distributed. The helpers below are no-ops
(or trivial) in a single process, so the trainer reads the same either way. No ROS import.
"""

from __future__ import annotations

import datetime as _dt
import os
from typing import Any

from deepbbs_ros.errors import ConfigError


def env_world_size() -> int:
    """``WORLD_SIZE`` set by torchrun (1 when not launched by it)."""
    try:
        return int(os.environ.get("WORLD_SIZE", "1"))
    except ValueError as err:
        raise ConfigError(f"WORLD_SIZE={os.environ.get('WORLD_SIZE')!r} is not a number") from err


def init_from_env(device: str = "auto", timeout_min: float = 60.0) -> str:
    """Join torchrun's process group; return this process's device name (``"cpu"`` or ``"cuda:N"``).

    ``device`` is the user's choice (``auto``, ``cpu``, ``cuda``, ``cuda:N``): ``auto`` or ``cuda`` means
    one GPU per process (``cuda:LOCAL_RANK``, NCCL) when CUDA is there, otherwise the CPU (gloo).
    """
    import torch
    import torch.distributed as dist

    from deepbbs_ros.device import resolve_device

    if dist.is_initialized():
        return device
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = resolve_device(device)
    if dev.type == "cuda":
        if device in ("auto", "cuda"):
            if local_rank >= torch.cuda.device_count():
                raise ConfigError(f"torchrun: local rank {local_rank} has no GPU ({torch.cuda.device_count()} "
                                  "GPU(s)); use --nproc_per_node <= GPUs or --device cpu")
            dev = torch.device("cuda", local_rank)
        torch.cuda.set_device(dev)
        backend = "nccl"
    else:
        backend = "gloo"
    try:
        dist.init_process_group(backend, timeout=_dt.timedelta(minutes=timeout_min))
    except (RuntimeError, ValueError) as err:
        raise ConfigError(f"torchrun: cannot join the process group ({str(err).splitlines()[0]})") from err
    return str(dev)


def destroy() -> None:
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def barrier() -> None:
    """Wait until every process gets here (nothing in a single process)."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        dist.barrier()


def world() -> tuple[int, int]:
    """(rank, world size): (0, 1) in a single process."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def all_gather(obj: Any) -> list[Any]:
    """Every process's ``obj`` (picklable), in rank order; ``[obj]`` in a single process."""
    import torch.distributed as dist

    rank, size = world()
    if size == 1:
        return [obj]
    out: list[Any] = [None] * size
    dist.all_gather_object(out, obj)
    return out


def reduce_mean(values: list[float], device: Any) -> list[float]:
    """The mean over the processes of each value (the values themselves in a single process)."""
    import torch
    import torch.distributed as dist

    rank, size = world()
    if size == 1:
        return list(values)
    t = torch.tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(t)
    return (t / size).tolist()


def agree(flags: list[bool], device: Any) -> list[bool]:
    """Rank 0's decisions (stop, save now, ...) for every process, so they all act at the same step."""
    import torch
    import torch.distributed as dist

    rank, size = world()
    if size == 1:
        return list(flags)
    t = torch.tensor([float(f) for f in flags], dtype=torch.float64, device=device)
    dist.broadcast(t, src=0)
    return [bool(v) for v in t.tolist()]
