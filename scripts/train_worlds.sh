#!/bin/sh
# The exact command behind the shipped model, trained on the realistic worlds (MODEL.md, "Training").
# Fine-tunes the previous shipped model (commit 33e1383, itself from
# scripts/train_default.sh) on newly simulated drives of the new worlds.
# Resumable: run it again after a stop. It continues from runs/worlds/state_latest.pt when that exists,
# else from the committed state deepbbs_ros/models/train_state/worlds/state_latest.pt (model, optimiser,
# scheduler, step, RNG states), else it starts from the previous model.
#   BUDGET=75 setsid nohup scripts/train_worlds.sh > runs/worlds.log 2>&1 &
# After a stop, commit the state: scripts/train_worlds.sh --save-state (copies the run's state, best
# model, validation history, curves and log into deepbbs_ros/models/train_state/worlds/).
# BUDGET: minutes of fitting this invocation (0 = until the schedule ends). THREADS: torch threads.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
RUN=${RUN:-runs/worlds}
STATE=deepbbs_ros/models/train_state/worlds
THREADS=${THREADS:-1}
BUDGET=${BUDGET:-0}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: 64 training drives of the new worlds (seeds 10000-10063, scene types cycled, randomised
#    sensor per drive: HDL-64/Ouster-64/HDL-32/VLP-16-like with perturbed beams, noise, dropouts and
#    mounting; 50 % motion-compensated, 30 % raw, 20 % ideal sweeps) x 25 frames, simulated in two
#    processes; 8 validation drives (80000-80007, HDL-64, compensated) x 30 frames
$T cache --out runs/cache/worlds_train --split train --seeds 10000:10032 --frames 25 --cache-points 4096 \
  --no-progress --threads 1 &
$T cache --out runs/cache/worlds_train --split train --seeds 10032:10064 --frames 25 --cache-points 4096 \
  --no-progress --threads 1 &
wait
$T cache --out runs/cache/worlds_val --split val --drives 8 --frames 30 --cache-points 4096 --no-progress

# 2. schedule: 60 epochs x 100 steps x batch 8 at 512 points per cloud (the inference size);
#    lr 5e-4 halved every 10 epochs; translation weighted 5x; from the previous shipped model.
#    (The first invocation ran with train.epochs=40 and was resumed with 60: the end of the schedule is
#    the only thing train.epochs sets, so the steps are those of this command.)
SETS="--set train.epochs=60 --set train.steps_per_epoch=100 --set train.batch_size=8 --set train.lr=5e-4 \
  --set train.lr_step=10 --set train.lr_gamma=0.5 --set train.val_every=2 --set train.val_pairs=16 \
  --set train.checkpoint_minutes=10 --set train.trans_weight=5 --set train.seed=2 --set train.num_points=512"
start_args 33e1383 init_previous_model.pt
# shellcheck disable=SC2086
$T fit --cache runs/cache/worlds_train --val-cache runs/cache/worlds_val --run "$RUN" --threads "$THREADS" \
  --no-progress $SETS $START $LIMIT
