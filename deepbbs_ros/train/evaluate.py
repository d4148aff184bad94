"""Accuracy of a model on held-out simulated Apollo-style drives: the figures of the model card.

Protocol (CONVENTIONS.md): HDL-64E-like drives (the simulator's default sensor), each sweep measured
while moving and motion-compensated to its stamp as Apollo's compensator publishes it (``raw_sweeps``:
the uncompensated sweeps instead, registered as they are), from the *test* seed range (90000 + i, never
used for training or validation; scene type ``scenes[i % len(scenes)]``); sources every ``stride``
frames, target = the last frame within ``max_dist`` (5 m) of the source; no initial guess (identity);
``preprocess.num_points`` points per cloud (512 by default). Every pair is registered twice: as it
comes, and with an extra random yaw of up to ``yaw_deg`` applied to the source scan (the ground truth
adjusted accordingly).

Methods: ``deepbbs++`` (the shipped pipeline as configured: deep passes + GICP precision stage by
default), ``deepbbs`` (the network alone: deep passes only, from the one start, no global search: the
network's own answer, not the best of the search's starts as the verdict judges them), ``refine-only`` (the 3D
SoftBBS refinement from identity, no network), ``gicp``
(small_gicp GICP from identity on the dense voxelised scan, the replay baseline, for contrast) and
``gicp-gt`` (the same GICP started at the ground truth: how far the dense clouds' own optimum lies
from the truth, i.e. the floor of rigid registration on the pair; large where a scene is degenerate,
e.g. along a corridor with little structure or with traffic moving at the ego's speed).
The DeepBBS variants share one preprocessing of each scan (the rotated source is the same points
rotated: preprocessing commutes with a yaw about the sensor axis up to the FPS start point), passed
as the ``PreprocessResult`` (with its dense points) when the registration takes one.

The summary, the goal checks and the tables are :mod:`deepbbs_ros.train.eval_report`'s.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.config.registration import NETWORK_ALONE
from deepbbs_ros.errors import ConfigError
from deepbbs_ros.metrics import pair_errors
from deepbbs_ros.train.cache import TEST_SEED_BASE
from deepbbs_ros.train.eval_report import (  # noqa: F401  (re-exported)
    GOALS,
    goal_checks,
    markdown_report,
    print_report,
    summarise,
)
from deepbbs_ros.train.rigid import inv_T, make_T, transform, yaw_matrix

METHODS = ("deepbbs++", "deepbbs", "refine-only", "gicp", "gicp-gt")


def evaluate(config: Config | None = None, *, weights: str | None = "", device: str | None = None,
             scenes: Sequence[str] | None = None, drives_per_scene: int = 4, seed_base: int | None = None,
             frames: int = 60, stride: int = 10, yaw_deg: float = 45.0, methods: Sequence[str] = METHODS,
             progress: bool = True, model=None, raw_sweeps: bool = False,
             rigs: Sequence[str] | None = None) -> dict[str, Any]:
    """Register held-out pairs with every method, with and without extra yaw.

    rigs: ``sensor:mount:place`` entries (e.g. ``avia:handheld:courtyard``) evaluated instead of ``scenes``
    (the HDL-64E car of the road drives); each is a "scene" of the report.

    Returns a JSON-friendly report: ``summary[variant][method][scene | "all"]`` with mean / RMSE /
    median / p95 / max rotation (deg) and translation (m) errors, success rate and runtime (ms), the
    goal checks, and every pair's errors under ``pairs``.
    """
    from tqdm import tqdm

    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.sim import SCENES
    from deepbbs_ros.sim.simulator import DriveSimulator
    from deepbbs_ros.train.cache import Drive
    from deepbbs_ros.train.pairs import protocol_pairs

    cfg = (config or Config()).validate()
    scenes = list(rigs or scenes or SCENES)
    methods = list(methods)
    for m in methods:
        if m not in METHODS:
            raise ConfigError(f"evaluate: unknown method {m!r} (known: {', '.join(METHODS)})")
    base = TEST_SEED_BASE if seed_base is None else int(seed_base)
    seeds = list(range(base, base + drives_per_scene * len(scenes)))

    # registration variants sharing one network
    regs: dict[str, Any] = {}
    full = DeepBBSRegistration(cfg, weights=weights, device=device, model=model)
    shared = {"model": full.model, "device": str(full.device)}
    cfg_used = full.config  # the checkpoint's model section, the run's other sections
    if "deepbbs++" in methods:
        regs["deepbbs++"] = full
    if "deepbbs" in methods:
        regs["deepbbs"] = DeepBBSRegistration(cfg_used.replace(**NETWORK_ALONE), **shared)
    if "refine-only" in methods:
        regs["refine-only"] = DeepBBSRegistration(
            cfg_used.replace(**{"registration.deep": False, "registration.refine": True,
                                "registration.polish": "none", "registration.global_search": "off"}), **shared)
    gicp = None
    if "gicp" in methods or "gicp-gt" in methods:
        from deepbbs_ros.baselines import SmallGicpRegistration

        gicp = SmallGicpRegistration("gicp", cfg_used)

    variants = [("plain", 0.0)] + ([("yaw", float(yaw_deg))] if yaw_deg > 0 else [])
    records: list[dict[str, Any]] = []
    rng = np.random.default_rng([base, 45])
    # pairs first (poses only, no ray casting), then cast only the frames that are needed
    plan = []
    for i, seed in enumerate(seeds):
        scene = scenes[i % len(scenes)]
        if rigs:
            from deepbbs_ros.sim.rig import make_simulator

            sensor, mount, place = _rig(scene)
            sim = make_simulator(place, seed, sensor, mount, frames=frames, compensate=not raw_sweeps)
        else:
            sim = DriveSimulator(scene, seed, frames=frames, compensate=not raw_sweeps)
        poses = np.stack([sim.pose_at(k) for k in range(frames)])
        fake = Drive(name=f"{scene}_{seed}", points=np.zeros((0, 3), np.float32),
                     offsets=np.zeros(frames + 1, np.int64), T_world_lidar=poses,
                     stamps_ns=np.zeros(frames, np.int64), meta={"scene": scene})
        plan.append((scene, seed, sim, protocol_pairs(fake, stride, cfg_used.eval.max_dist)))
    total = sum(len(p[3]) for p in plan)
    bar = tqdm(total=total, unit="pairs", desc="evaluate", disable=not progress)
    t_start = time.perf_counter()
    for scene, seed, sim, pairs in plan:
        cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

        def frame(k: int, sim=sim, cache=cache) -> tuple[np.ndarray, np.ndarray]:
            if k not in cache:
                scan = sim.scan_at(k)
                cache[k] = (scan.points, full.preprocess(scan.points))
            return cache[k]

        for i, j in pairs:
            (raw_s, pre_s), (raw_t, pre_t) = frame(i), frame(j)
            T_gt0 = inv_T(sim.pose_at(j)) @ sim.pose_at(i)
            pt = gicp.preprocess(raw_t) if gicp is not None else None  # the target is the same in every variant
            pair = {"scene": scene, "seed": seed, "i": i, "j": j, "dist_m": float(np.linalg.norm(T_gt0[:3, 3]))}

            for variant, ydeg in variants:
                A = make_T(yaw_matrix(np.deg2rad(rng.uniform(-ydeg, ydeg))), np.zeros(3)) if ydeg else np.eye(4)
                T_gt = T_gt0 @ inv_T(A)
                nb = cfg_used.registration.polish_neighbors
                src, tgt = _moved(pre_s, A, nb), _moved(pre_t, np.eye(4), nb)
                for name, reg in regs.items():
                    t0 = time.perf_counter()
                    res = reg.register(src, tgt, preprocessed=True)
                    ms = (time.perf_counter() - t0) * 1e3
                    records.append(_record(pair, variant, name, res.T_target_source, T_gt, ms))
                if gicp is not None:
                    ps = gicp.preprocess(transform(raw_s, A))
                    for name, init in (("gicp", None), ("gicp-gt", T_gt)):
                        if name in methods:
                            t0 = time.perf_counter()
                            res = gicp.align(ps, pt, init)
                            ms = (time.perf_counter() - t0) * 1e3 + ps.preprocess_ms + pt.preprocess_ms
                            records.append(_record(pair, variant, name, res.T_target_source, T_gt, ms))
            bar.update(1)
    bar.close()

    summary = summarise(records, [v for v, _ in variants], methods, scenes, cfg_used)
    goals = goal_checks(summary)
    return {
        "protocol": {"seeds": [seeds[0], seeds[-1]], "scenes": scenes, "drives_per_scene": drives_per_scene,
                     "frames": frames, "stride": stride, "max_dist_m": cfg_used.eval.max_dist, "yaw_deg": yaw_deg,
                     "sensor": ("the rigs (sensor:mount:place), " if rigs else "hdl64 (simulator default), ")
                               + ("raw sweeps (motion-distorted)" if raw_sweeps else "sweeps compensated to the stamp"),
                     "initial_guess": "identity",
                     "num_points": cfg_used.preprocess.num_points,
                     "success": {"rot_deg": cfg_used.eval.success_rot_deg, "trans_m": cfg_used.eval.success_trans}},
        "weights": str(weights) if weights else "shipped default",
        "model_metadata": _meta_brief(getattr(full, "metadata", None)),
        "seconds": round(time.perf_counter() - t_start, 1),
        "summary": summary,
        "goals": goals,
        "pairs": records,
    }


def _rig(spec: str) -> tuple[str, str, str]:
    """``sensor:mount:place`` -> its three parts; a one-line :class:`ConfigError` otherwise."""
    parts = spec.split(":")
    if len(parts) != 3 or not all(parts):
        raise ConfigError(f"evaluate: rig {spec!r} is not sensor:mount:place (e.g. avia:handheld:courtyard)")
    return parts[0], parts[1], parts[2]


def _record(pair: dict[str, Any], variant: str, method: str, T_est: np.ndarray, T_gt: np.ndarray,
            ms: float) -> dict[str, Any]:
    """One row of ``report["pairs"]``: the pair's identity, the method and its errors against T_gt."""
    r, t = pair_errors(T_est, T_gt)
    return {"variant": variant, "method": method, **pair, "rot_err_deg": float(r), "trans_err_m": float(t), "ms": ms}


def _moved(prep: Any, A: np.ndarray, neighbors: int = 20) -> Any:
    """A preprocessed scan moved by A: the ``PreprocessResult`` itself (with its dense points, for the
    dense refinement) when the registration accepts one, else its sampled points."""
    import dataclasses

    if getattr(prep, "dense_points", None) is None or not dataclasses.is_dataclass(prep):
        return transform(prep.points, A)
    pc = getattr(prep, "polish_cloud", None)
    if pc is not None and not np.array_equal(A, np.eye(4)):
        pc = pc.transformed(A, neighbors)
    return dataclasses.replace(prep, points=transform(prep.points, A), dense_points=transform(prep.dense_points, A),
                               polish_cloud=pc)


def _meta_brief(meta: Any) -> Any:
    if not isinstance(meta, dict):
        return None
    return {k: meta[k] for k in ("step", "epoch", "train_seconds", "saved_utc") if k in meta}
