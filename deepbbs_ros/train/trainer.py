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

A step is here, the loop that runs them :mod:`deepbbs_ros.train.fit_loop`'s; the state file, checkpoints and resume
are :mod:`deepbbs_ros.train.run_state`'s, the logs and the report :mod:`deepbbs_ros.train.run_log`'s, the held-out
pairs, errors and score :mod:`deepbbs_ros.train.validation`'s.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import numpy as np

from deepbbs_ros.config import Config
from deepbbs_ros.train.anchor import anchor_of, sp_distance2
from deepbbs_ros.train.cache import Drive
from deepbbs_ros.train.fit_loop import train_loop
from deepbbs_ros.train.loss import deepbbs_loss, loss_options
from deepbbs_ros.train.pairs import AugmentConfig, Pair, PairSampler, collate
from deepbbs_ros.train.run_log import append_log, write_val_csv
from deepbbs_ros.train.run_state import restore_state, save_state
from deepbbs_ros.train.validation import ValidationSet, score, validation_record


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
        from deepbbs_ros.train.distributed import world

        self.config = config.validate()
        tc = config.train
        self.rank, self.world_size = world()
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
        # L2-SP (train.sp_weight, train/anchor.py): the weights the run starts from; a resume restores the saved ones
        self.sp_anchor = anchor_of(self.model) if tc.sp_weight > 0 else None
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
        terms = deepbbs_loss(out, src, tgt, R_gt, t_gt, **loss_options(self.config, self.epoch))
        total, sp_dist = terms.total, 0.0
        if self.sp_anchor is not None:
            d2 = sp_distance2(self.model, self.sp_anchor)
            total, sp_dist = total + 0.5 * tc.sp_weight * d2, float(d2.detach()) ** 0.5
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        grad_norm = float("nan")
        if tc.grad_clip > 0:
            grad_norm = float(torch.nn.utils.clip_grad_norm_(self.model.parameters(), tc.grad_clip))
        values = [float(total.detach()), float(terms.rot), float(terms.trans), float(terms.corr),
                  float(terms.partner_ratio), float(terms.kept)]
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
            "kept": values[5], "grad_norm": grad_norm, "skipped": 0.0 if finite else 1.0, "sp_dist": sp_dist,
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
        vs = self.validation_set()
        if vs is None:
            return None
        return validation_record(self.model, self.config, vs, self.val_drives, self.device, self.step, self.epoch)

    score = staticmethod(score)  # higher is better (:func:`deepbbs_ros.train.validation.score`)

    # -- checkpoints and logs (run_state.py, run_log.py) ---------------------------------------------
    def save(self, val: dict[str, Any] | None = None, best: bool = False) -> None:
        """Write ``state_latest.pt`` and ``model_latest.pt`` (and ``model_best.pt`` when ``best``).
        With several processes every rank calls it (their generators are gathered); rank 0 writes."""
        save_state(self, val, best)

    def resume(self, path: str | Path | None = None) -> int:
        """Restore everything from ``state_latest.pt`` (or ``path``). Returns the step reached."""
        return restore_state(self, path)

    def _log(self, rec: dict[str, Any]) -> None:
        if self.is_main:
            append_log(self.run_dir, rec)

    def _write_val_csv(self) -> None:
        if self.is_main:
            write_val_csv(self.run_dir, self.history)

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
        return train_loop(self, max_steps, time_budget_s)
