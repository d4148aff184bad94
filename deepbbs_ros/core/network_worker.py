"""The network process's side (no ROS import): the worker :class:`~deepbbs_ros.core.network_process.NetworkProcess`
starts, with the checkpoint's :class:`~deepbbs_ros.core.network.DeepBBSNetwork` on the CPU, answering its requests.
Started as ``python -m deepbbs_ros.core.network_process FD``.
"""

from __future__ import annotations

from typing import Any

from deepbbs_ros.core.worker_process import started


def _build(weights: str, flat_config: dict[str, Any]) -> tuple[Any, tuple]:
    """The worker's network (on the CPU, in its process), warmed up for the search's batches -> ((it, its config),
    the ``("ready",)`` answer)."""
    from deepbbs_ros.config import Config
    from deepbbs_ros.core.network import DeepBBSNetwork

    cfg = Config.from_flat({**flat_config, "registration.network_process": "off", "registration.device": "cpu"})
    net = DeepBBSNetwork(cfg, weights=weights)
    from deepbbs_ros.core.search_starts import batch_sizes, rank_size  # the search's batches

    net.warmup(batches=batch_sizes(cfg.registration)[0],
               rank_points=rank_size(cfg.registration, cfg.preprocess.num_points))
    return (net, cfg), ("ready",)


def _worker_main(fd: int) -> int:
    """The worker: read (weights, flat config), load the checkpoint, warm up, then answer
    ("run", src, tgt, T_init[, speculate]) (a second answer with the speculative starts' outputs) and ("starts",
    src, tgt, T_starts, n_passes), and take ("target", tgt) ahead of a run (no answer) and ("cancel",) (no answer),
    until ("stop",) or until the caller is gone (EOF)."""
    conn, built, rc = started(fd, _build)
    if built is None:
        return rc
    net, cfg = built
    from deepbbs_ros.core.search_starts import rank_size  # (imported by _build)

    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return 0
        if msg[0] == "target":
            try:
                net.prepare_target_np(msg[1])
            except Exception:  # noqa: BLE001 - best effort: the run that follows computes it and reports
                pass
            continue
        if msg[0] == "cancel":  # it came after the speculative passes were done
            continue
        if msg[0] not in ("run", "starts"):
            return 0
        try:
            out = net.network_np(*msg[1:4]) if msg[0] == "run" else net.starts_np(*msg[1:])
            conn.send(("ok", out))
            if msg[0] == "run" and len(msg) > 4:  # the global search's other starts, until another message comes
                k = rank_size(cfg.registration, min(len(msg[1]), len(msg[2])))  # the ranking passes' points
                conn.send(("ok", net.speculate_np(msg[1][:k], msg[2][:k], msg[4], stop=lambda: conn.poll(0))))
        except (EOFError, OSError):
            return 0
        except Exception as err:  # noqa: BLE001 - the caller raises it as a RegistrationError
            conn.send(("error", f"{type(err).__name__}: {err}"))
