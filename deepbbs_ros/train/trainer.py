"""The training loop: Adam with a step-decayed learning rate, periodic validation through the full
DeepBBS++ inference path, checkpoints (latest + best) and exact resume.

A run folder holds:

* ``state_latest.pt``: everything a resume needs (model, optimiser, scheduler, step, the numpy
  generator that draws pairs, torch / python RNG states, history, best score);
* ``model_latest.pt``, ``model_best.pt``: weights in the shipped checkpoint format
  (``deepbbs_ros.core.checkpoint``), loadable by the node and every CLI with ``--weights``;
* ``log.jsonl``: one JSON record per training step (``"kind": "train"``) and per validation
  (``"kind": "val"``); ``val.csv``: the validation records as a table;
* ``curves.png``: loss and validation error curves; ``config.yaml``: the configuration used;
  ``val_best.json``: the validation figures of ``model_best.pt``.

Determinism: all randomness of the data comes from one ``numpy.random.Generator`` owned by the
trainer, the model's from torch's global generator; both are saved, so running 2 + 2 steps with a
resume in between gives the same weights as 4 steps straight.

Several processes (``torchrun``, :mod:`deepbbs_ros.train.distributed`): the network is wrapped in
``DistributedDataParallel``, every process draws its own ``train.batch_size`` pairs from its own
generator (seeded with the seed and its rank), gradients are averaged, and every decision that ends or
saves (time budget, periodic checkpoints, a non-finite loss) is rank 0's, taken by all at the same step.
Rank 0 alone validates and writes files; the state file holds every rank's generators (``ranks``), so a
resume with the same number of processes continues exactly.
"""

from __future__ import annotations

import csv
import json
import math
import random
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ModelError
from deepbbs_ros.train.cache import Drive
from deepbbs_ros.train.loss import deepbbs_loss
from deepbbs_ros.train.pairs import AugmentConfig, Pair, PairSampler, collate, validation_pairs

STATE_FILE = "state_latest.pt"
LATEST_MODEL = "model_latest.pt"
BEST_MODEL = "model_best.pt"


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """arccos((trace(R_gt^T R) - 1) / 2) in degrees (CONVENTIONS.md)."""
    c = (np.trace(R_gt.T @ R_est) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def pair_errors(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(rot_err_deg, trans_err_m) of one estimate against the ground truth."""
    return rotation_error_deg(T_est[:3, :3], T_gt[:3, :3]), float(np.linalg.norm(T_est[:3, 3] - T_gt[:3, 3]))


def summarize_errors(rot: list[float], trans: list[float], rot_thr: float, trans_thr: float) -> dict[str, float]:
    """Mean / median / p95 / max of both errors and the success rate (both within thresholds)."""
    r, t = np.asarray(rot, dtype=np.float64), np.asarray(trans, dtype=np.float64)
    if len(r) == 0:
        return {"n": 0}
    ok = (r <= rot_thr) & (t <= trans_thr)
    return {
        "n": int(len(r)),
        "rot_mean_deg": float(r.mean()), "rot_median_deg": float(np.median(r)),
        "rot_p95_deg": float(np.percentile(r, 95)), "rot_max_deg": float(r.max()),
        "trans_mean_m": float(t.mean()), "trans_median_m": float(np.median(t)),
        "trans_p95_m": float(np.percentile(t, 95)), "trans_max_m": float(t.max()),
        "success": float(ok.mean()),
    }


@dataclass
class ValidationSet:
    """Fixed held-out pairs: as they come (``plain``) and with an extra random yaw (``yaw``)."""

    plain: list[Pair]
    yaw: list[Pair]
    yaw_deg: float

    @classmethod
    def build(cls, drives: list[Drive], config: Config, num_points: int, *, max_pairs: int = 32,
              stride: int = 10) -> ValidationSet:
        tc = config.train
        per_drive = max(1, math.ceil(max_pairs / max(1, len(drives))))
        plain = validation_pairs(drives, num_points, stride=stride, max_dist=tc.max_dist, seed=tc.seed,
                                 per_drive=per_drive)[:max_pairs]
        yaw = validation_pairs(drives, num_points, stride=stride, max_dist=tc.max_dist, yaw_deg=tc.yaw_aug_deg,
                               seed=tc.seed + 1, per_drive=per_drive)[:max_pairs]
        return cls(plain, yaw, tc.yaw_aug_deg)


class Trainer:
    """Trains a ``DeepBBSNet`` on cached drives.

    Args:
        config: the whole configuration (``train``, ``model``, ``preprocess``, ``registration``).
        run_dir: output folder (created).
        train_drives: cached training drives (see :mod:`deepbbs_ros.train.cache`).
        val_drives: held-out drives for validation, or None to skip validation.
        device: "auto" | "cpu" | "cuda[:N]"; None = ``config.registration.device``.
        model: an already built network (tests, fine-tuning); None = a fresh ``DeepBBSNet(config.model)``.
        progress: show a tqdm bar.
        curves: redraw ``curves.png`` at every epoch end.
        meta: extra metadata stored in every checkpoint (data description, command line).
        sampler: where training pairs come from (``batch(rng, n)``, ``num_pairs``); None = a ``PairSampler`` over
            ``train_drives`` (adaptation passes its pseudo-labels, :mod:`deepbbs_ros.train.adapt`).
    """

    def __init__(self, config: Config, run_dir: str | Path, train_drives: list[Drive],
                 val_drives: list[Drive] | None = None, *, device: str | None = None, model=None,
                 progress: bool = True, meta: dict[str, Any] | None = None, curves: bool = True, sampler=None):
        import torch

        from deepbbs_ros.core.model import DeepBBSNet
        from deepbbs_ros.device import resolve_device
        from deepbbs_ros.train import distributed

        self.config = config.validate()
        tc = config.train
        self.rank, self.world_size = distributed.world()
        self.is_main = self.rank == 0
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.device = resolve_device(device or config.registration.device)
        self.progress = progress and self.is_main
        self.curves = curves
        self.meta = dict(meta or {})
        self.num_points = tc.num_points or config.preprocess.num_points

        # deterministic seeds: torch (init + model randomness), python, and the data generator
        torch.manual_seed(tc.seed)
        random.seed(tc.seed)
        self.rng = np.random.default_rng(tc.seed if self.world_size == 1 else [tc.seed, self.rank])

        self.model = (model if model is not None else DeepBBSNet(config.model)).to(self.device)
        self.net = self.model  # what a training step calls: the model, or its DistributedDataParallel wrapper
        if self.world_size > 1:
            from torch.nn.parallel import DistributedDataParallel

            # rank 0's weights are broadcast here; gradients are averaged in backward()
            self.net = DistributedDataParallel(self.model, device_ids=[self.device.index]
                                               if self.device.type == "cuda" else None)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=tc.lr)
        self.scheduler = torch.optim.lr_scheduler.StepLR(
            self.optimizer, step_size=tc.lr_step * tc.steps_per_epoch, gamma=tc.lr_gamma
        )
        self.sampler = sampler or PairSampler(train_drives, AugmentConfig.from_train(tc, self.num_points))
        self.val_drives = val_drives or []
        self._val_set: ValidationSet | None = None
        self.step = 0
        self.train_seconds = 0.0
        self.best_score: list[float] | None = None
        self.best_val: dict[str, Any] | None = None
        self.history: list[dict[str, Any]] = []
        self._tail: list[dict[str, Any]] = []
        self.meta.setdefault("train_drives", len(train_drives))
        self.meta.setdefault("train_pairs", self.sampler.num_pairs)
        if self.world_size > 1:
            self.meta["processes"] = self.world_size

    # -- properties --------------------------------------------------------------------------
    @property
    def epoch(self) -> int:
        return self.step // self.config.train.steps_per_epoch

    @property
    def total_steps(self) -> int:
        return self.config.train.epochs * self.config.train.steps_per_epoch

    # -- one step --------------------------------------------------------------------------------
    def train_step(self, pairs: list[Pair] | None = None) -> dict[str, float]:
        """One optimiser step on ``pairs`` (drawn from the sampler when None). Returns the loss terms."""
        import torch

        tc = self.config.train
        if pairs is None:
            pairs = self.sampler.batch(self.rng, tc.batch_size)
        src, tgt, R_gt, t_gt = (x.to(self.device) for x in collate(pairs))
        self.model.train()
        out = self.net(src, tgt)
        terms = deepbbs_loss(out, src, tgt, R_gt, t_gt, scale=self.config.model.scale, theta=tc.theta,
                             corr_weight=tc.beta ** self.epoch, trans_weight=tc.trans_weight)
        self.optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        grad_norm = float("nan")
        if tc.grad_clip > 0:
            grad_norm = float(torch.nn.utils.clip_grad_norm_(self.model.parameters(), tc.grad_clip))
        values = [float(terms.total.detach()), float(terms.rot), float(terms.trans), float(terms.corr),
                  float(terms.partner_ratio)]
        if self.world_size > 1:  # the mean over the processes: one non-finite loss skips the step everywhere
            from deepbbs_ros.train.distributed import reduce_mean

            values = reduce_mean(values, self.device)
        finite = math.isfinite(values[0])
        if finite:
            self.optimizer.step()
        self.scheduler.step()
        self.step += 1
        return {
            "loss": values[0], "rot": values[1], "trans": values[2], "corr": values[3], "partners": values[4],
            "grad_norm": grad_norm, "skipped": 0.0 if finite else 1.0,
        }

    # -- validation --------------------------------------------------------------------------------
    def validation_set(self) -> ValidationSet | None:
        if not self.val_drives:
            return None
        if self._val_set is None:
            # validation sees what inference sees: preprocess.num_points per cloud
            self._val_set = ValidationSet.build(self.val_drives, self.config, self.config.preprocess.num_points,
                                                max_pairs=self.config.train.val_pairs)
        return self._val_set

    def validate(self) -> dict[str, Any] | None:
        """Errors of the full DeepBBS++ registration (deep iterations + refinement) on the fixed
        held-out pairs, with and without the extra yaw, plus the one-pass network loss."""
        import torch

        from deepbbs_ros.core.registration import DeepBBSRegistration

        vs = self.validation_set()
        if vs is None:
            return None
        cfg, tc = self.config, self.config.train
        t0 = time.perf_counter()
        self.model.eval()
        reg = DeepBBSRegistration(cfg, model=self.model, device=str(self.device))
        rec: dict[str, Any] = {"kind": "val", "step": self.step, "epoch": self.epoch}
        with torch.no_grad():
            # one network pass on the plain pairs: the validation loss
            losses = []
            for k in range(0, len(vs.plain), tc.batch_size):
                src, tgt, R_gt, t_gt = (x.to(self.device) for x in collate(vs.plain[k : k + tc.batch_size]))
                out = self.model(src, tgt)
                terms = deepbbs_loss(out, src, tgt, R_gt, t_gt, scale=cfg.model.scale, theta=tc.theta,
                                     corr_weight=tc.beta ** self.epoch, trans_weight=tc.trans_weight)
                losses.append(float(terms.total) * len(src))
            rec["val_loss"] = sum(losses) / max(1, len(vs.plain))
            folder = {d.name: str(d.meta.get("cache", "")) for d in self.val_drives}
            groups: dict[str, dict[str, Any]] = {}
            for name, pairs in (("plain", vs.plain), ("yaw", vs.yaw)):
                rot, trans, group = [], [], []
                for p in pairs:
                    res = reg.register(p.source, p.target, preprocessed=True)
                    r, t = pair_errors(res.T_target_source, p.T_target_source)
                    rot.append(r)
                    trans.append(t)
                    group.append(folder.get(p.ref.split(":")[0], ""))
                rec[name] = summarize_errors(rot, trans, cfg.eval.success_rot_deg, cfg.eval.success_trans)
                for g in sorted(set(group)):  # each validation folder apart (e.g. a sensor mix and HDL-64E roads)
                    k = [i for i, x in enumerate(group) if x == g]
                    groups.setdefault(g, {})[name] = summarize_errors(
                        [rot[i] for i in k], [trans[i] for i in k], cfg.eval.success_rot_deg, cfg.eval.success_trans)
            if len(groups) > 1:
                rec["groups"] = groups
        self.model.train()
        rec["seconds"] = round(time.perf_counter() - t0, 2)
        return rec

    @staticmethod
    def score(rec: dict[str, Any]) -> list[float]:
        """Higher is better: total success rate, then lower mean rotation and translation errors. With
        several validation folders each weighs the same (a mix of sensors cannot outvote HDL-64E roads)."""
        parts = list(rec["groups"].values()) if rec.get("groups") else [rec]
        n = len(parts)
        return [sum(g[s]["success"] for g in parts for s in ("plain", "yaw")) / n,
                -sum(g[s]["rot_mean_deg"] for g in parts for s in ("plain", "yaw")) / n,
                -sum(g[s]["trans_mean_m"] for g in parts for s in ("plain", "yaw")) / n]

    # -- checkpoints ---------------------------------------------------------------------------
    def _model_meta(self, val: dict[str, Any] | None) -> dict[str, Any]:
        return {**self.meta, "step": self.step, "epoch": self.epoch, "train_seconds": round(self.train_seconds, 1),
                "num_points": self.num_points, "validation": val, "saved_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ",
                                                                                             time.gmtime())}

    def _rank_state(self) -> dict[str, Any]:
        """This process's generators and a digest of its weights (the same on every rank when in sync)."""
        import hashlib

        import torch

        digest = hashlib.sha256()
        for v in self.model.state_dict().values():
            digest.update(v.detach().cpu().contiguous().numpy().tobytes())
        return {"rank": self.rank, "np_rng": self.rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                "cuda_rng": torch.cuda.get_rng_state(self.device) if self.device.type == "cuda" else None,
                "py_rng": random.getstate(), "weights_sha256": digest.hexdigest()}

    def save(self, val: dict[str, Any] | None = None, best: bool = False) -> None:
        """Write ``state_latest.pt`` and ``model_latest.pt`` (and ``model_best.pt`` when ``best``).
        With several processes every rank calls it (their generators are gathered); rank 0 writes."""
        import torch

        from deepbbs_ros.core.checkpoint import save_checkpoint

        ranks = None
        if self.world_size > 1:
            from deepbbs_ros.train.distributed import all_gather

            ranks = all_gather(self._rank_state())
            if not self.is_main:
                return
        state = {
            "format": "deepbbs_ros.train/1",
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "step": self.step,
            "train_seconds": self.train_seconds,
            "np_rng": self.rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
            "py_rng": random.getstate(),
            "best_score": self.best_score,
            "best_val": self.best_val,
            "history": self.history,
            "config": self.config.to_dict(),
            "meta": self.meta,
            "world_size": self.world_size,
            "ranks": ranks,
        }
        tmp = self.run_dir / (STATE_FILE + ".tmp")
        torch.save(state, tmp)
        tmp.replace(self.run_dir / STATE_FILE)
        last_val = val or next((h for h in reversed(self.history) if h.get("kind") == "val"), None)
        save_checkpoint(self.run_dir / LATEST_MODEL, self.model, self.config, self._model_meta(last_val))
        if best:
            save_checkpoint(self.run_dir / BEST_MODEL, self.model, self.config, self._model_meta(val))
            (self.run_dir / "val_best.json").write_text(json.dumps(self._model_meta(val), indent=2))

    def resume(self, path: str | Path | None = None) -> int:
        """Restore everything from ``state_latest.pt`` (or ``path``). Returns the step reached."""
        import torch

        path = Path(path) if path else self.run_dir / STATE_FILE
        if path.is_dir():
            path = path / STATE_FILE
        if not path.exists():
            raise ModelError(f"resume: no training state at {path}")
        try:
            state = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as err:  # noqa: BLE001 - any unpickling failure means a corrupt file
            raise ModelError(f"resume: {path} is not a readable training state ({err})") from err
        if state.get("format") != "deepbbs_ros.train/1":
            raise ModelError(f"resume: {path} is not a deepbbs-train state file")
        saved_model = state["config"]["model"]
        if saved_model != self.config.to_dict()["model"]:
            raise ModelError(f"resume: {path} was trained with a different model config ({saved_model})")
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.step = int(state["step"])
        self.train_seconds = float(state.get("train_seconds", 0.0))
        self.rng.bit_generator.state = state["np_rng"]
        torch.set_rng_state(state["torch_rng"])
        if state.get("cuda_rng") is not None and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(state["cuda_rng"])
        random.setstate(state["py_rng"])
        saved_world = int(state.get("world_size") or 1)
        ranks = state.get("ranks") or []
        if self.world_size > 1:
            if self.rank < len(ranks):  # this rank's own generators
                mine = ranks[self.rank]
                self.rng.bit_generator.state = mine["np_rng"]
                torch.set_rng_state(mine["torch_rng"])
                if mine.get("cuda_rng") is not None and self.device.type == "cuda":
                    torch.cuda.set_rng_state(mine["cuda_rng"], self.device)
                random.setstate(mine["py_rng"])
            else:  # a rank the saved run did not have: a fresh generator of its own
                self.rng = np.random.default_rng([self.config.train.seed, self.rank, self.step])
        if saved_world != self.world_size and self.is_main:
            print(f"deepbbs-train: resuming a state saved by {saved_world} process(es) with {self.world_size}: "
                  "weights, optimiser and schedule continue, the order of the pairs differs", file=sys.stderr)
        self.best_score = state.get("best_score")
        self.best_val = state.get("best_val")
        self.history = list(state.get("history", []))
        if self.is_main:
            self._truncate_log()
        return self.step

    # -- logs ------------------------------------------------------------------------------------
    def _log(self, rec: dict[str, Any]) -> None:
        if not self.is_main:
            return
        with open(self.run_dir / "log.jsonl", "a") as fh:
            fh.write(json.dumps(rec) + "\n")

    def _truncate_log(self) -> None:
        """After a resume, drop log records written after the restored step (they will be redone)."""
        log = self.run_dir / "log.jsonl"
        if not log.exists():
            return
        keep = [ln for ln in log.read_text().splitlines() if ln.strip() and json.loads(ln).get("step", 0) <= self.step]
        log.write_text("".join(k + "\n" for k in keep))

    def _write_val_csv(self) -> None:
        vals = [h for h in self.history if h.get("kind") == "val"]
        if not vals or not self.is_main:
            return
        cols = ["step", "epoch", "val_loss"] + [f"{s}_{k}" for s in ("plain", "yaw")
                                                  for k in ("rot_mean_deg", "trans_mean_m", "success")]
        with open(self.run_dir / "val.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(cols)
            for v in vals:
                w.writerow([v["step"], v["epoch"], f"{v['val_loss']:.6g}"]
                           + [f"{v[s][k]:.6g}" for s in ("plain", "yaw") for k in ("rot_mean_deg", "trans_mean_m",
                                                                                    "success")])

    def plot(self) -> Path | None:
        """``curves.png``: training loss (smoothed) and validation loss; validation errors and success."""
        from deepbbs_ros.train.plots import plot_curves

        log = self.run_dir / "log.jsonl"
        if not self.curves or not self.is_main or not log.exists():
            return None
        return plot_curves(log, self.run_dir / "curves.png")

    def _recent(self, n: int) -> list[dict[str, Any]]:
        return self._tail[-n:]

    # -- the loop --------------------------------------------------------------------------------
    def fit(self, max_steps: int | None = None, time_budget_s: float | None = None) -> dict[str, Any]:
        """Train until ``config.train.epochs`` (or ``max_steps`` more steps, or the time budget).

        Validates every ``val_every`` epochs, saves the latest state at every epoch end and every
        ``checkpoint_minutes``, and the best model by :meth:`score`. Ctrl-C / SIGTERM save first.
        """
        from tqdm import tqdm

        tc = self.config.train
        end = self.total_steps if max_steps is None else min(self.total_steps, self.step + max_steps)
        if self.is_main:
            (self.run_dir / "config.yaml").write_text(self.config.to_yaml())
        t_start = time.perf_counter()
        last_save = time.perf_counter()
        bar = tqdm(total=end, initial=self.step, unit="step", desc="train", disable=not self.progress,
                   dynamic_ncols=True, file=sys.stderr)
        try:
            while self.step < end:
                t0 = time.perf_counter()
                terms = self.train_step()
                dt = time.perf_counter() - t0
                self.train_seconds += dt
                rec = {"kind": "train", "step": self.step, "epoch": (self.step - 1) // tc.steps_per_epoch,
                       "lr": self.optimizer.param_groups[0]["lr"], "s_per_step": round(dt, 4),
                       **{k: round(v, 7) for k, v in terms.items()}}
                self._log(rec)
                self._tail.append(rec)
                del self._tail[:-10]
                bar.update(1)
                bar.set_postfix(loss=f"{terms['loss']:.4g}", s_step=f"{dt:.2f}", epoch=rec["epoch"])
                if not self.progress and self.is_main and self.step % 10 == 0:  # plain progress lines for log files
                    m = {k: np.mean([r[k] for r in self._recent(10)]) for k in ("loss", "rot", "trans", "corr",
                                                                                 "s_per_step")}
                    print(f"step {self.step}/{end} epoch {rec['epoch']} loss {m['loss']:.4g} (rot {m['rot']:.3g} "
                          f"trans {m['trans']:.3g} corr {m['corr']:.3g}) {m['s_per_step']:.2f} s/step "
                          f"lr {rec['lr']:.3g} {time.strftime('%H:%M:%S')}", flush=True)
                epoch_end = self.step % tc.steps_per_epoch == 0
                if epoch_end:
                    val = None
                    if self.val_drives and self.is_main and (self.epoch % tc.val_every == 0 or self.step >= end):
                        try:
                            val = self.validate()
                        except Exception:  # noqa: BLE001 - a long unattended run keeps training; the bug is logged
                            traceback.print_exc()
                            bar.write(f"validation failed at step {self.step} (traceback above); training goes on")
                            self.model.train()
                    if val is not None:
                        val["train_seconds"] = round(self.train_seconds, 1)
                        self.history.append(val)
                        self._log(val)
                        self._write_val_csv()
                        bar.write(format_val(val))
                        sys.stdout.flush()
                    is_best = False
                    if val is not None:
                        sc = self.score(val)
                        if self.best_score is None or sc > self.best_score:
                            self.best_score, self.best_val, is_best = sc, val, True
                    elif not self.val_drives:
                        is_best = True  # without validation the latest is the best we know
                    self.save(val, best=is_best)
                    self.plot()
                    last_save = time.perf_counter()
                save_now = (not epoch_end and tc.checkpoint_minutes > 0
                            and time.perf_counter() - last_save > 60 * tc.checkpoint_minutes)
                stop = time_budget_s is not None and time.perf_counter() - t_start > time_budget_s
                if self.world_size > 1:  # rank 0's clock decides for every process
                    from deepbbs_ros.train.distributed import agree

                    save_now, stop = agree([save_now, stop], self.device)
                if save_now:
                    self.save()
                    last_save = time.perf_counter()
                if stop:
                    if self.is_main:
                        bar.write(f"time budget of {time_budget_s:.0f} s reached at step {self.step}")
                    break
        except KeyboardInterrupt:
            if self.world_size > 1:  # the processes may be at different steps: keep the last common save
                if self.is_main:
                    print(f"interrupted at step {self.step}: the state saved last in {self.run_dir / STATE_FILE} "
                          "is kept (resume from it)", file=sys.stderr)
                raise
            bar.write(f"interrupted at step {self.step}: saving {self.run_dir / STATE_FILE}")
            self.save()
            self.plot()
            raise
        finally:
            bar.close()
        if self.step % tc.steps_per_epoch:
            self.save()
        self.plot()
        return {"step": self.step, "epoch": self.epoch, "train_seconds": self.train_seconds,
                "best_val": self.best_val}


def format_val(val: dict[str, Any]) -> str:
    p, y = val["plain"], val["yaw"]
    return (f"val step {val['step']} (epoch {val['epoch']}): loss {val['val_loss']:.4g} | "
            f"plain rot {p['rot_mean_deg']:.3f} deg trans {p['trans_mean_m']:.3f} m success {100 * p['success']:.1f}% "
            f"| +yaw rot {y['rot_mean_deg']:.3f} deg trans {y['trans_mean_m']:.3f} m success "
            f"{100 * y['success']:.1f}% ({val['seconds']:.0f} s)"
            + "".join(f" | {g} success {100 * v['plain']['success']:.1f}% / +yaw {100 * v['yaw']['success']:.1f}%"
                      for g, v in val.get("groups", {}).items()))


def run_report(run_dir: str | Path) -> str:
    """Markdown: steps done, training time, seconds per step (by points per cloud), and the validation
    history of a run folder (from ``log.jsonl``)."""
    run_dir = Path(run_dir)
    log = run_dir / "log.jsonl"
    if not log.exists():
        raise ModelError(f"report: no log.jsonl in {run_dir}")
    train, vals = [], []
    for ln in log.read_text().splitlines():
        if ln.strip():
            rec = json.loads(ln)
            (vals if rec.get("kind") == "val" else train).append(rec)
    out = [f"Run `{run_dir}`: {len(train)} steps"]
    if train:
        secs = sum(r["s_per_step"] for r in train)
        out[0] += (f", {secs / 60:.1f} min of training steps ({np.median([r['s_per_step'] for r in train]):.2f} "
                   f"s/step median), {sum(v.get('seconds', 0) for v in vals) / 60:.1f} min of validation")
    out += ["", "| step | epoch | val loss | rot (deg) | trans (m) | success (%) | +yaw rot (deg) | +yaw trans (m) "
            "| +yaw success (%) |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for v in vals:
        p, y = v["plain"], v["yaw"]
        out.append(f"| {v['step']} | {v['epoch']} | {v['val_loss']:.4g} | {p['rot_mean_deg']:.3f} | "
                   f"{p['trans_mean_m']:.3f} | {100 * p['success']:.1f} | {y['rot_mean_deg']:.3f} | "
                   f"{y['trans_mean_m']:.3f} | {100 * y['success']:.1f} |")
    best = run_dir / "val_best.json"
    if best.exists():
        b = json.loads(best.read_text())
        out += ["", f"Best checkpoint `{run_dir / BEST_MODEL}`: step {b.get('step')} (epoch {b.get('epoch')}), "
                    f"saved {b.get('saved_utc')}."]
    return "\n".join(out)
