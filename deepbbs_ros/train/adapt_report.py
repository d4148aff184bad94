"""The before / after report of an adaptation, on the recording's held-back scans (its poses graded here only).

Pairs follow the replay protocol on the held-back frames (a source every ``stride`` frames, the target the last
later frame within ``max_dist`` metres). Each is registered by the network with its global search (the row
"network + search": ``config.registration.NETWORK_ALONE`` but the global search's other starts as configured; no
refinement, no precision stage) and by the shipped pipeline (as configured), from the
pair's true relative start (identity) and from ``trials`` perturbed starts (a random yaw up to ``yaw_deg`` and a
shift up to ``trans_m``). A pair succeeds within ``eval.success_rot_deg`` / ``eval.success_trans`` and is in the
basin within :data:`BASIN` (5 degrees / 1 m: where GICP takes over); for the pipeline
the verdict's acceptances and the wrong ones among them are counted too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.config.registration import NETWORK_ALONE
from deepbbs_ros.train.pseudo import pose_error

METHODS = ("network", "pipeline")  # the keys of report.json
#: each method's row in report.md: "network" is the network with the global search's other starts (the network alone
#: of ``deepbbs-replay`` / ``deepbbs-train evaluate``, ``NETWORK_ALONE``, has no search)
ROWS = {"network": "network + search", "pipeline": "pipeline"}
BASIN = (5.0, 1.0)  # deg, m: close enough for the precision stage to finish (the network row's figure that counts)


def held_pairs(T_world_lidar: np.ndarray, frames: list[int], stride: int, max_dist: float) -> list[tuple[int, int]]:
    """(source i, target j): i every ``stride`` held-back frames, j the last later held-back frame within
    ``max_dist`` m of i."""
    out = []
    for a in range(0, len(frames) - 1, stride):
        i = frames[a]
        later = [j for j in frames[a + 1:] if np.linalg.norm(T_world_lidar[j, :3, 3] - T_world_lidar[i, :3, 3])
                 <= max_dist]
        if later:
            out.append((i, later[-1]))
    return out


def method_config(config: Config, method: str) -> Config:
    """``config`` for ``method``: "network" is ``NETWORK_ALONE`` with the global search left as configured."""
    if method == "network":
        return config.replace(**{k: v for k, v in NETWORK_ALONE.items() if k != "registration.global_search"})
    return config


def evaluate_held(config: Config, weights: str, prepared: list[Any], T_world_lidar: np.ndarray,
                  pairs: list[tuple[int, int]], *, yaw_deg: float = 45.0, trans_m: float = 2.0, trials: int = 2,
                  seed: int = 0, device: str | None = None) -> dict[str, Any]:
    """Success (and for the pipeline, verdicts) of ``weights`` ("" = the shipped model) on ``pairs`` of the
    preprocessed scans ``prepared``. The perturbed starts are the same for every weights (``seed``)."""
    from deepbbs_ros.core.registration import DeepBBSRegistration
    from deepbbs_ros.replay.runner import random_perturbation

    ev = config.eval
    rng = np.random.default_rng([seed, 38])
    inits = {p: [random_perturbation(rng, yaw_deg, trans_m) for _ in range(trials)] for p in pairs}
    out: dict[str, Any] = {"pairs": len(pairs)}
    for method in METHODS:
        reg = DeepBBSRegistration(method_config(config, method), weights=weights or None, device=device)
        try:
            rec: dict[str, Any] = {}
            for start in ("identity", "perturbed"):
                ok = acc = acc_wrong = n = 0
                rots, trs = [], []
                for i, j in pairs:
                    T_gt = np.linalg.inv(T_world_lidar[j]) @ T_world_lidar[i]
                    for T_init in ([None] if start == "identity" else inits[(i, j)]):
                        res = reg.register(prepared[i], prepared[j], T_init=T_init)
                        rot, tr = pose_error(res.T_target_source, T_gt)
                        good = rot <= ev.success_rot_deg and tr <= ev.success_trans
                        rots.append(rot)
                        trs.append(tr)
                        n += 1
                        ok += int(good)
                        acc += int(res.valid)
                        acc_wrong += int(res.valid and not good)
                basin = np.mean((np.asarray(rots) <= BASIN[0]) & (np.asarray(trs) <= BASIN[1])) if n else 0.0
                rec[start] = {"n": n, "success": round(ok / max(1, n), 4), "basin": round(float(basin), 4),
                              "rot_median_deg": round(float(np.median(rots)), 3) if n else None,
                              "trans_median_m": round(float(np.median(trs)), 3) if n else None}
                if method == "pipeline":
                    rec[start].update(accepted=acc, accepted_wrong=acc_wrong)
            out[method] = rec
        finally:
            reg.close()
    return out


def markdown(before: dict[str, Any], after: dict[str, Any] | None, labels: dict[str, Any], cost: dict[str, Any],
             ) -> str:
    """The report as Markdown: the labels, then success before / after per method and start."""
    lines = [f"Pseudo-labels: {labels.get('accepted', 0)} accepted, {labels.get('kept', 0)} kept after "
             f"{labels.get('triplets', 0)} triplets ({labels.get('triplets_agreeing', 0)} agreeing)."]
    q = labels.get("against_poses")
    if q:
        lines.append(f"Against the recording's poses (not used for training): {q['accepted_wrong']} of "
                     f"{q['accepted']} accepted wrong, {q['kept_wrong']} of {q['kept']} kept wrong, "
                     f"{q['rejected_right']} right answers rejected.")
    if cost:
        lines.append(f"Training: {cost.get('steps')} steps, {cost.get('train_seconds', 0) / 60:.1f} min "
                     f"({cost.get('s_per_step')} s/step).")
    if not before.get("pairs"):
        lines.append("No held-back pairs with poses: no before / after figures.")
        return "\n".join(lines) + "\n"
    lines += ["", f"Held-back pairs: {before['pairs']} (success within 1 deg / 0.3 m and within 5 deg / 1 m, %)", "",
              "| method | start | before | after | 5 deg / 1 m before / after | accepted before / after "
              "| wrong accepted before / after |", "|---|---|---:|---:|---:|---:|---:|"]
    for method in METHODS:
        for start in ("identity", "perturbed"):
            b = before[method][start]
            a = (after or {}).get(method, {}).get(start, {})
            av = f"{100 * a['success']:.1f}" if a else "-"
            basin = f"{100 * b['basin']:.1f} / " + (f"{100 * a['basin']:.1f}" if a else "-")
            acc = wrong = ""
            if method == "pipeline":
                acc = f"{b['accepted']} / {a.get('accepted', '-')} of {b['n']}"
                wrong = f"{b['accepted_wrong']} / {a.get('accepted_wrong', '-')}"
            lines.append(f"| {ROWS[method]} | {start} | {100 * b['success']:.1f} | {av} | {basin} | {acc} | {wrong} |")
    return "\n".join(lines) + "\n"
