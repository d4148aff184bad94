"""The training loop behind :meth:`deepbbs_ros.train.trainer.Trainer.fit`: a step at a time, each logged (and a plain
progress line every 10 steps for log files); at every epoch end the validation, the best model and a save; between
them a save every ``train.checkpoint_minutes``; the time budget; Ctrl-C / SIGTERM save first.

With several processes every decision that ends or saves is rank 0's, taken by all at the same step. The trainer is
passed in (its step, the logs, save, validate, plot): this module does not import it.
"""

from __future__ import annotations

import sys
import time
import traceback
from typing import Any

import numpy as np

from deepbbs_ros.train.run_state import STATE_FILE
from deepbbs_ros.train.validation import format_val


def train_loop(tr, max_steps: int | None = None, time_budget_s: float | None = None) -> dict[str, Any]:
    """Train ``tr`` (a ``Trainer``) until ``config.train.epochs`` (or ``max_steps`` more steps, or the time budget)."""
    from tqdm import tqdm

    tc = tr.config.train
    end = tr.total_steps if max_steps is None else min(tr.total_steps, tr.step + max_steps)
    if tr.is_main:
        (tr.run_dir / "config.yaml").write_text(tr.config.to_yaml())
    t_start = time.perf_counter()
    last_save = time.perf_counter()
    bar = tqdm(total=end, initial=tr.step, unit="step", desc="train", disable=not tr.progress,
               dynamic_ncols=True, file=sys.stderr)
    try:
        while tr.step < end:
            t0 = time.perf_counter()
            terms = tr.train_step()
            _logged(tr, bar, terms, time.perf_counter() - t0, end)
            epoch_end = tr.step % tc.steps_per_epoch == 0
            if epoch_end:
                _end_epoch(tr, bar, end)
                last_save = time.perf_counter()
            save_now = (not epoch_end and tc.checkpoint_minutes > 0
                        and time.perf_counter() - last_save > 60 * tc.checkpoint_minutes)
            stop = time_budget_s is not None and time.perf_counter() - t_start > time_budget_s
            if tr.world_size > 1:  # rank 0's clock decides for every process
                from deepbbs_ros.train.distributed import agree

                save_now, stop = agree([save_now, stop], tr.device)
            if save_now:
                tr.save()
                last_save = time.perf_counter()
            if stop:
                if tr.is_main:
                    bar.write(f"time budget of {time_budget_s:.0f} s reached at step {tr.step}")
                break
    except KeyboardInterrupt:
        _interrupted(tr, bar)
        raise
    finally:
        bar.close()
    if tr.step % tc.steps_per_epoch:
        tr.save()
    tr.plot()
    return {"step": tr.step, "epoch": tr.epoch, "train_seconds": tr.train_seconds, "best_val": tr.best_val}


def _logged(tr, bar, terms: dict[str, float], dt: float, end: int) -> None:
    """A step's record (``log.jsonl``, the trainer's last 10), the bar, and every 10 steps without a bar a plain line
    of the last 10 steps' means."""
    tc = tr.config.train
    tr.train_seconds += dt
    rec = {"kind": "train", "step": tr.step, "epoch": (tr.step - 1) // tc.steps_per_epoch,
           "lr": tr.optimizer.param_groups[0]["lr"], "s_per_step": round(dt, 4),
           **{k: round(v, 7) for k, v in terms.items()}}
    tr._log(rec)
    tr._tail.append(rec)
    del tr._tail[:-10]
    bar.update(1)
    bar.set_postfix(loss=f"{terms['loss']:.4g}", s_step=f"{dt:.2f}", epoch=rec["epoch"])
    if not tr.progress and tr.is_main and tr.step % 10 == 0:  # plain progress lines for log files
        m = {k: np.mean([r[k] for r in tr._recent(10)]) for k in ("loss", "rot", "trans", "corr", "s_per_step")}
        print(f"step {tr.step}/{end} epoch {rec['epoch']} loss {m['loss']:.4g} (rot {m['rot']:.3g} "
              f"trans {m['trans']:.3g} corr {m['corr']:.3g}) {m['s_per_step']:.2f} s/step "
              f"lr {rec['lr']:.3g} {time.strftime('%H:%M:%S')}", flush=True)


def _end_epoch(tr, bar, end: int) -> None:
    """At an epoch's end: validate (every ``train.val_every`` epochs and at the last step; rank 0), log it, keep the
    best by the trainer's score (without validation the latest is the best), save and redraw the curves."""
    tc = tr.config.train
    val = None
    if tr.val_drives and tr.is_main and (tr.epoch % tc.val_every == 0 or tr.step >= end):
        try:
            val = tr.validate()
        except Exception:  # noqa: BLE001 - a long unattended run keeps training; the bug is logged
            traceback.print_exc()
            bar.write(f"validation failed at step {tr.step} (traceback above); training goes on")
            tr.model.train()
    if val is not None:
        val["train_seconds"] = round(tr.train_seconds, 1)
        tr.history.append(val)
        tr._log(val)
        tr._write_val_csv()
        bar.write(format_val(val))
        sys.stdout.flush()
    is_best = False
    if val is not None:
        sc = tr.score(val)
        if tr.best_score is None or sc > tr.best_score:
            tr.best_score, tr.best_val, is_best = sc, val, True
    elif not tr.val_drives:
        is_best = True  # without validation the latest is the best we know
    tr.save(val, best=is_best)
    tr.plot()


def _interrupted(tr, bar) -> None:
    """Ctrl-C: one process saves its state and curves; with several (maybe at different steps) the last common save
    is kept."""
    if tr.world_size > 1:
        if tr.is_main:
            print(f"interrupted at step {tr.step}: the state saved last in {tr.run_dir / STATE_FILE} "
                  "is kept (resume from it)", file=sys.stderr)
        return
    bar.write(f"interrupted at step {tr.step}: saving {tr.run_dir / STATE_FILE}")
    tr.save()
    tr.plot()
