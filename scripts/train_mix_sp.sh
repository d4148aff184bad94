#!/bin/sh
# A sensor-mix fine-tune held near the shipped weights by L2-SP (docs/training.md, "Held near the shipped weights"):
# the mix runs' schedule (MIX_SCHEDULE, scripts/train_mix_data.sh) from the shipped weights on the 64 HDL-64E road
# drives the shipped model was trained on and DRIVES mix drives compensated to their stamps (scripts/train_mix_clean.sh's
# data, every pair in the loss: HARD=0) with one change: each step's loss gains SP/2 ||w - w_shipped||^2
# (train.sp_weight, deepbbs_ros/train/anchor.py). SP = 0.4 makes the pull back to the shipped weights, at the
# distance the road drives alone moved them in 400 steps (scripts/train_control.sh: 0.337), as strong as the median
# gradient of those steps (0.130): the mix may move the network as far as the roads did, and further only where its
# gradient outweighs that pull.
# Validated every 100 steps on 2 pairs of each of the 16 compensated mix and the 8 HDL-64E road validation drives (each folder weighing
# the same): runs/NAME/model_best.pt; the weights are also copied every CHUNK steps to runs/NAME/stepN.pt.
#   STEPS=400 nice -n 10 scripts/train_mix_sp.sh > runs/mix_sp.log 2>&1 &
#   scripts/train_mix_sp.sh --save-state      # copy the run's state to deepbbs_ros/models/train_state/NAME
# Resumable: runs/NAME/state_latest.pt, else the committed deepbbs_ros/models/train_state/NAME/state_latest.pt
# (the shipped weights the term pulls towards are in it), else the shipped weights with a fresh optimiser.
# NAME: run and state folder name. SP: train.sp_weight. HARD: train.hard_pair_deg. DRIVES: mix drives.
# STEPS: steps this call trains. CHUNK: steps between copies of the weights. THREADS: torch threads.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
NAME=${NAME:-mix_sp}
RUN=${RUN:-runs/$NAME}
CACHE=${CACHE:-runs/cache}
STATE=deepbbs_ros/models/train_state/$NAME
SP=${SP:-0.4}
HARD=${HARD:-0}
DRIVES=${DRIVES:-64}
STEPS=${STEPS:-400}
CHUNK=${CHUNK:-100}
THREADS=${THREADS:-1}
T="$PY -m deepbbs_ros.cli.train"

. scripts/train_resume.sh
if [ "${1:-}" = "--save-state" ]; then save_state; exit 0; fi

# 1. data: scripts/train_mix_clean.sh's (the mix drives compensated, the road drives) and the validation folders
. scripts/train_mix_data.sh
if [ ! -d "$CACHE/mixclean_train" ]; then mix_train mixclean --sweeps compensated; fi
if [ ! -d "$CACHE/worlds_train" ]; then road_train; fi
if [ ! -d "$CACHE/mixclean_val" ]; then mix_val mixclean --sweeps compensated; fi
if [ ! -d "$CACHE/worlds_val" ]; then road_val; fi

# 2. fit: MIX_SCHEDULE, validated every epoch, and the pull to the shipped weights, CHUNK steps at a time
SETS="$MIX_SCHEDULE --set train.checkpoint_minutes=0 --set train.val_every=1 --set train.val_pairs=48 \
  --set train.hard_pair_deg=$HARD --set train.sp_weight=$SP"
if [ -f "$STATE/state_latest.pt" ]; then FIRST="--resume $STATE/state_latest.pt"; else FIRST="--init shipped"; fi
fit_chunks "$FIRST" --cache "$CACHE/mixclean_train" --cache "$CACHE/worlds_train" \
  --val-cache "$CACHE/mixclean_val" --val-cache "$CACHE/worlds_val"
