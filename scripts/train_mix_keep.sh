#!/bin/sh
# The second sensor-mix run (MODEL.md, "The sensor mix"): fine-tunes the shipped model on the world's sensors
# while keeping the HDL-64E car on the road where it is. The first run (scripts/train_mix.sh) drew pairs by
# count: its handheld, legged and wheeled drives move slowly (median pair 0.8 m apart, against 1.8 m on the
# roads) and outnumber the roads 8:1 in pairs, and the network learnt to shorten translations (HDL-64E road
# pairs 4.7 m apart: 1.0-1.3 m short, against 0.3-0.9 m for the shipped model). Here every drive weighs the
# same and a drive's pairs are drawn uniform in distance (train.pair_balance=distance), half the mix's drives
# (128: the roads a third of the draws), lr 5e-5 halved every 3 epochs of 100 steps, validation every 200
# steps on both folders (mix, HDL-64E roads), each weighing the same in the choice of model_best.pt.
# Resumable: run it again after a stop; it continues from runs/mix_keep/state_latest.pt, else from the
# committed deepbbs_ros/models/train_state/mix_keep/state_latest.pt, else from the shipped model.
#   UNTIL=07:35 setsid nohup nice -n 10 scripts/train_mix_keep.sh > runs/mix_keep.log 2>&1 &
#   scripts/train_mix_keep.sh --save-state     # commit the state after a stop
# BUDGET: minutes of fitting this invocation (0 = until the schedule ends); UNTIL (HH:MM, UTC) sets BUDGET
# to the minutes left until then once the caches are made. THREADS: torch threads. DRIVES: mix drives.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
RUN=${RUN:-runs/mix_keep}
CACHE=${CACHE:-runs/cache}
STATE=deepbbs_ros/models/train_state/mix_keep
THREADS=${THREADS:-1}
BUDGET=${BUDGET:-0}
DRIVES=${DRIVES:-128}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: scripts/train_mix_data.sh (scripts/train_mix.sh's draws), fewer drives
. scripts/train_mix_data.sh
mix_data mix

# 2. schedule: 12 epochs x 100 steps x batch 8 at 512 points; lr 5e-5 halved every 3 epochs; translation
#    weighted 5x; validation every 2 epochs on 48 pairs (2 per drive, each folder weighing the same)
SETS="--set train.epochs=12 --set train.steps_per_epoch=100 --set train.batch_size=8 --set train.lr=5e-5 \
  --set train.pair_balance=distance --set train.lr_step=3 --set train.lr_gamma=0.5 --set train.val_every=2 --set train.val_pairs=48 \
  --set train.checkpoint_minutes=10 --set train.trans_weight=5 --set train.seed=3 --set train.num_points=512"
if [ -n "${UNTIL:-}" ]; then
  BUDGET=$(( ($(date -u -d "$UNTIL" +%s) - $(date -u +%s)) / 60 ))
  if [ "$BUDGET" -lt 1 ]; then echo "UNTIL $UNTIL: no time left" >&2; exit 1; fi
  echo "budget: $BUDGET min (until $UNTIL UTC)"
fi
start_args 960ef7d init_shipped_model.pt
# shellcheck disable=SC2086
$T fit --cache "$CACHE/mix_train" --cache "$CACHE/worlds_train" --val-cache "$CACHE/mix_val" \
  --val-cache "$CACHE/worlds_val" --run "$RUN" --threads "$THREADS" --no-progress $SETS $START $LIMIT
