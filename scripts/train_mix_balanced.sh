#!/bin/sh
# The sensor-mix runs with every drive alike and pairs drawn uniform in distance (MODEL.md, "The sensor mix"):
# scripts/train_mix_keep.sh (the second run) and scripts/train_mix_span.sh (the third and fourth) set NAME and
# MIX_DATA and call this script; see their headers for what each run changes and why. It fine-tunes the shipped
# model on the world's sensors while keeping the HDL-64E car on the road where it is: every drive weighs the same
# and a drive's pairs are drawn uniform in distance (train.pair_balance=distance), half the mix's drives (128: the
# roads a third of the draws), lr 5e-5 halved every 3 epochs of 100 steps, validation every 200 steps on both
# folders (mix, HDL-64E roads), each weighing the same in the choice of model_best.pt.
# Resumable: run it again after a stop; it continues from runs/NAME/state_latest.pt, else from the committed
# deepbbs_ros/models/train_state/NAME/state_latest.pt, else from the shipped model.
# NAME: run and state folder name (runs/NAME, deepbbs_ros/models/train_state/NAME). MIX_DATA: the mix cache's
# name ($CACHE/MIX_DATA_train, _val) and its `deepbbs-train cache` options (e.g. "mix_span --min-span 10").
# POSE_LOSS: train.pose_loss (unset: the config's). BUDGET: minutes of fitting this invocation (0 = until the
# schedule ends); UNTIL (HH:MM, UTC) sets BUDGET to the minutes left until then once the caches are made.
# THREADS: torch threads. DRIVES: mix drives. --save-state: commit the run's state after a stop.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
NAME=${NAME:?NAME: the run (mix_keep, mix_span, ...)}
MIX_DATA=${MIX_DATA:?MIX_DATA: the mix cache name and its cache options}
RUN=${RUN:-runs/$NAME}
CACHE=${CACHE:-runs/cache}
STATE=deepbbs_ros/models/train_state/$NAME
THREADS=${THREADS:-1}
BUDGET=${BUDGET:-0}
DRIVES=${DRIVES:-128}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: scripts/train_mix_data.sh (scripts/train_mix.sh's draws), fewer drives
. scripts/train_mix_data.sh
# shellcheck disable=SC2086
mix_data $MIX_DATA
set -- $MIX_DATA
MIX=$1

# 2. schedule: MIX_SCHEDULE (scripts/train_mix_data.sh: 12 epochs x 100 steps x batch 8 at 512 points; lr 5e-5
#    halved every 3 epochs; translation weighted 5x; pairs balanced by distance); validation every 2 epochs on 48
#    pairs (2 per drive, each folder weighing the same)
SETS="$MIX_SCHEDULE --set train.val_every=2 --set train.val_pairs=48 --set train.checkpoint_minutes=10"
if [ -n "${POSE_LOSS:-}" ]; then SETS="$SETS --set train.pose_loss=$POSE_LOSS"; fi
if [ -n "${UNTIL:-}" ]; then
  BUDGET=$(( ($(date -u -d "$UNTIL" +%s) - $(date -u +%s)) / 60 ))
  if [ "$BUDGET" -lt 1 ]; then echo "UNTIL $UNTIL: no time left" >&2; exit 1; fi
  echo "budget: $BUDGET min (until $UNTIL UTC)"
fi
start_args 960ef7d init_shipped_model.pt
# shellcheck disable=SC2086
$T fit --cache "$CACHE/${MIX}_train" --cache "$CACHE/worlds_train" --val-cache "$CACHE/${MIX}_val" \
  --val-cache "$CACHE/worlds_val" --run "$RUN" --threads "$THREADS" --no-progress $SETS $START $LIMIT
