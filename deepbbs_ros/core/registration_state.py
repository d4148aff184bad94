"""What the stages of one ``DeepBBSRegistration.register`` call share (no ROS): the state from the inputs to the
result, the guard that reads a pending answer of the network process when a stage raises, and the result."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from deepbbs_ros.core.network_output import Clock
from deepbbs_ros.core.network_runner import NetworkRunner
from deepbbs_ros.core.polish import PolishCloud
from deepbbs_ros.core.preprocess import PreprocessResult
from deepbbs_ros.core.refine import NeighbourSearch
from deepbbs_ros.core.result import RegistrationResult

__all__ = ["State", "answer_read", "to_result"]


@dataclass
class State:
    """What the stages of one ``register`` call share: the clouds (numpy, and scaled (1, N, 3) tensors on
    the device), the estimate R (3, 3), t (3,) in scaled units (T: the float64 metres matrix once the
    network stages are done), and the bookkeeping of the result."""

    src_np: np.ndarray
    tgt_np: np.ndarray
    src_dense: np.ndarray | None
    tgt_dense: np.ndarray | None
    src_pre: PreprocessResult | None
    tgt_pre: PreprocessResult | None
    src_pc: PolishCloud | None
    tgt_pc: PolishCloud | None
    src: torch.Tensor
    tgt: torch.Tensor
    search: NeighbourSearch
    R: torch.Tensor
    t: torch.Tensor
    gamma: torch.Tensor
    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    iters: dict[str, int] = field(default_factory=lambda: {"deep": 0, "refine": 0, "dense": 0, "polish": 0})
    converged: bool = False
    temperature: float = 0.0
    inlier_ratio: float = 0.0
    polish_reason: str = ""
    deskew: str = ""
    skew: str = ""  # the skew check's finding (core/sweep_skew.py): "rejected: ...", "passed: ...", "" not run
    T_start: np.ndarray = field(default_factory=lambda: np.eye(4))  # the given start (the global search turns it)
    score: float = float("nan")  # the verdict's fitness (core/verdict.py)
    probability: float = float("nan")  # the verdict: P(right)
    valid: bool = False
    ambiguity: Any = None  # core.second_minimum.Ambiguity of the verdict's check (None: not checked)
    vouched: bool = False  # register(good_start=True) with a T_init: the caller vouches for the start
    rival: str = ""  # the search's answer ambiguous with another candidate (core/search_ambiguity.py): why
    starts: int = 1
    others: Any = None  # the global search's other starts, ranked: [(score, NetworkOutput, T)]
    replaced: Any = None  # (R, t, gamma) of the given start's answer when the search replaced it
    pending: Any = None  # a network_process.Pending while the network process works
    spec: Any = None  # the same, for its speculative passes from the global search's other starts
    spec_n: int = 0  # how many of those starts it was given (the first ones)
    yaw_search: bool = True  # register(yaw_search=False): the global search does not run for this call
    polish_check: tuple[int, float] | None = None  # register(polish_check=...): core.polish.polish's check
    network_ms: dict[str, float] = field(default_factory=dict)  # its embed / match / solve times


@contextlib.contextmanager
def answer_read(st: State) -> Iterator[None]:
    """An answer of the network process still pending when a stage raises is read and dropped: the worker
    takes one request at a time, and the next registration must not get this one's answer."""
    try:
        yield
    finally:
        pending, st.pending = st.pending, None
        NetworkRunner.discard(pending)  # read and dropped; speculative passes after it (if any) stopped
        spec, st.spec = st.spec, None
        NetworkRunner.drop(spec)


def to_result(st: State, clock: Clock) -> RegistrationResult:
    """The :class:`RegistrationResult` of a finished call: its pose, verdict, bookkeeping and stage timings."""
    stages = ("preprocess", "embed", "match", "solve", "refine") + (("dense",) if st.iters["dense"] else ())
    stages += tuple(s for s in ("good_start", "network_wait", "polish", "deskew", "global") if s in clock.ms)
    timings = {s: clock.ms.get(s, 0.0) for s in stages}
    timings["total"] = sum(timings.values())  # the wall time of register(), less the start-up
    if "startup" in clock.ms:  # the network process's start (first call): its own figure, not in the total
        timings["startup"] = clock.ms["startup"]
    for s, v in st.network_ms.items():  # ran in the network process, overlapping "preprocess"
        timings[s] = v
    return RegistrationResult(
        T_target_source=st.T,
        converged=bool(st.converged),
        iterations=st.iters,
        gamma=st.gamma.float().cpu().numpy(),
        inlier_ratio=st.inlier_ratio,
        temperature=st.temperature,
        timings_ms=timings,
        source=st.src_np,
        target=st.tgt_np,
        polish=st.polish_reason,
        deskew=st.deskew,
        skew=st.skew,
        valid=bool(st.valid),
        score=float(st.score),
        probability=float(st.probability),
        starts=int(st.starts),
        path="search" if st.starts > 1 else "deepbbs",
    )
