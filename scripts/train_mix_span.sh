#!/bin/sh
# The third sensor-mix run (MODEL.md, "The sensor mix"): scripts/train_mix_keep.sh with the mix drives' frames
# spread over 10 m of travel. At 10 Hz, 25 consecutive sweeps of a handheld, legged or wheeled drive (0.5-1.5 m/s)
# travel 1-3 m: those drives had no pair farther apart than that, though the registration is asked (and evaluated)
# up to train.max_dist (5 m). `deepbbs-train cache --min-span 10` keeps every s-th sweep of a drive (s the smallest
# stride, at most 10, whose 25 frames travel 10 m: 2-8 for the slow mounts, 1-2 for a car), so every drive has
# pairs from 0 to 5 m and `train.pair_balance: distance` draws them uniform in distance. The road replay and the
# HDL-64E validation drives are those of the other runs; everything else (seeds, sensors, mounts, places,
# schedule) is scripts/train_mix_keep.sh's.
# Resumable: run it again after a stop; it continues from runs/mix_span/state_latest.pt, else from the
# committed deepbbs_ros/models/train_state/mix_span/state_latest.pt, else from the shipped model.
#   UNTIL=10:30 setsid nohup nice -n 10 scripts/train_mix_span.sh > runs/mix_span.log 2>&1 &
#   scripts/train_mix_span.sh --save-state     # commit the state after a stop
# The fourth run (the bounded per-pair pose loss, train.pose_loss=bounded) is this script with its own run and
# state folders:
#   NAME=mix_bound POSE_LOSS=bounded UNTIL=13:25 setsid nohup nice -n 10 scripts/train_mix_span.sh > runs/mix_bound.log 2>&1 &
#   NAME=mix_bound scripts/train_mix_span.sh --save-state
# BUDGET: minutes of fitting this invocation (0 = until the schedule ends); UNTIL (HH:MM, UTC) sets BUDGET
# to the minutes left until then once the caches are made. THREADS: torch threads. DRIVES: mix drives.
# NAME: run and state folder name (runs/NAME, deepbbs_ros/models/train_state/NAME). POSE_LOSS: train.pose_loss.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
NAME=${NAME:-mix_span}
RUN=${RUN:-runs/$NAME}
CACHE=${CACHE:-runs/cache}
STATE=deepbbs_ros/models/train_state/$NAME
THREADS=${THREADS:-1}
BUDGET=${BUDGET:-0}
DRIVES=${DRIVES:-128}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: scripts/train_mix_data.sh (scripts/train_mix_keep.sh's draws), frames spread over 10 m
. scripts/train_mix_data.sh
mix_data mix_span --min-span 10

# 2. schedule: scripts/train_mix_keep.sh's (12 epochs x 100 steps x batch 8 at 512 points; lr 5e-5 halved every 3
#    epochs; translation weighted 5x; pairs balanced by distance; validation every 2 epochs on 48 pairs)
SETS="--set train.epochs=12 --set train.steps_per_epoch=100 --set train.batch_size=8 --set train.lr=5e-5 \
  --set train.pair_balance=distance --set train.lr_step=3 --set train.lr_gamma=0.5 --set train.val_every=2 --set train.val_pairs=48 \
  --set train.checkpoint_minutes=10 --set train.trans_weight=5 --set train.seed=3 --set train.num_points=512"
if [ -n "${POSE_LOSS:-}" ]; then SETS="$SETS --set train.pose_loss=$POSE_LOSS"; fi
if [ -n "${UNTIL:-}" ]; then
  BUDGET=$(( ($(date -u -d "$UNTIL" +%s) - $(date -u +%s)) / 60 ))
  if [ "$BUDGET" -lt 1 ]; then echo "UNTIL $UNTIL: no time left" >&2; exit 1; fi
  echo "budget: $BUDGET min (until $UNTIL UTC)"
fi
start_args 960ef7d init_shipped_model.pt
# shellcheck disable=SC2086
$T fit --cache "$CACHE/mix_span_train" --cache "$CACHE/worlds_train" --val-cache "$CACHE/mix_span_val" \
  --val-cache "$CACHE/worlds_val" --run "$RUN" --threads "$THREADS" --no-progress $SETS $START $LIMIT
