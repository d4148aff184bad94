#!/bin/sh
# The exact command behind the mix model: the network fine-tuned on the world's sensors, mounts and places
# (MODEL.md, "The mix"). Starts from the shipped model (itself from scripts/train_worlds.sh).
# Resumable: run it again after a stop. It continues from runs/mix/state_latest.pt when that exists,
# else from the committed state deepbbs_ros/models/train_state/mix/state_latest.pt (model, optimiser,
# scheduler, step, RNG states), else it starts from the shipped model. Caches already made are kept.
#   BUDGET=60 setsid nohup scripts/train_mix.sh > runs/mix.log 2>&1 &
# After a stop, commit the state: scripts/train_mix.sh --save-state (copies the run's state, best
# model, validation history, curves and log into deepbbs_ros/models/train_state/mix/).
# BUDGET: minutes of fitting this invocation (0 = until the schedule ends). THREADS: torch threads.
# DRIVES: training drives of the mix (the committed run: 256).
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
RUN=${RUN:-runs/mix}
CACHE=${CACHE:-runs/cache}
STATE=deepbbs_ros/models/train_state/mix
THREADS=${THREADS:-1}
BUDGET=${BUDGET:-0}
DRIVES=${DRIVES:-256}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: scripts/train_mix_data.sh, DRIVES mix drives (the committed run: 256)
. scripts/train_mix_data.sh
mix_data mix

# 2. schedule: 16 epochs x 100 steps x batch 8 at 512 points per cloud (the inference size); lr 1e-4
#    halved every 5 epochs; translation weighted 5x; validation every 2 epochs on 48 pairs (2 per drive,
#    each folder weighing the same in the model selection); from the shipped model. (A first try at lr 3e-4,
#    halved every 9 epochs, lost on both validation folders over its first 400 steps and was stopped.)
SETS="--set train.epochs=16 --set train.steps_per_epoch=100 --set train.batch_size=8 --set train.lr=1e-4 \
  --set train.lr_step=5 --set train.lr_gamma=0.5 --set train.val_every=2 --set train.val_pairs=48 \
  --set train.checkpoint_minutes=10 --set train.trans_weight=5 --set train.seed=2 --set train.num_points=512"
start_args 960ef7d init_shipped_model.pt
# shellcheck disable=SC2086
$T fit --cache "$CACHE/mix_train" --cache "$CACHE/worlds_train" --val-cache "$CACHE/mix_val" \
  --val-cache "$CACHE/worlds_val" --run "$RUN" --threads "$THREADS" --no-progress $SETS $START $LIMIT
