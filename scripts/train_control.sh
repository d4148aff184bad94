#!/bin/sh
# A control for the sensor-mix fine-tunes (docs/training.md, "A control: the mix runs' procedure on the road
# drives alone"):
# the mix runs' schedule (scripts/train_mix_keep.sh / train_mix_span.sh: batch 8 at 512 points, lr 5e-5 halved
# every 3 epochs of 100 steps, translation weighted 5x, pairs balanced by distance, seed 3) on the shipped model's
# OWN training drives (scripts/train_worlds.sh's cache runs/cache/worlds_train) instead of the mix. The weights are
# copied every CHUNK steps to runs/NAME/stepN.pt for `deepbbs-train evaluate --weights runs/NAME/stepN.pt`.
#   NAME=ctl_fresh STEPS=300 nice -n 10 scripts/train_control.sh > runs/ctl_fresh.log 2>&1 &
# START: shipped (the shipped weights, a fresh optimiser at step 0: what the mix runs do) or a state file to
#   resume exactly (weights, optimiser, schedule, step), e.g. deepbbs_ros/models/train_state/worlds/state_latest.pt.
# SETS_EXTRA: more --set options, one change at a time (e.g. "--set train.lr=1.5625e-5").
# MORE: more training cache folders beside the road drives (e.g. "--cache runs/cache/mixcar_train": sensor-mix
#   drives on car roofs only, `deepbbs-train cache ... --mounts car` with scripts/train_mix_data.sh's seeds, places
#   and sensors; runs/cache/mixslow_train the same with --mounts wheeled,legged,handheld), to split the mix.
# STEPS: steps this call trains; CHUNK: steps between copies of the weights. THREADS: torch threads.
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
NAME=${NAME:-ctl_fresh}
RUN=runs/$NAME
CACHE=${CACHE:-runs/cache}
START=${START:-shipped}
STEPS=${STEPS:-300}
CHUNK=${CHUNK:-100}
THREADS=${THREADS:-1}
T="$PY -m deepbbs_ros.cli.train"

if [ ! -d "$CACHE/worlds_train" ]; then
  echo "no $CACHE/worlds_train: make it as scripts/train_worlds.sh does (step 1)" >&2; exit 1
fi
. scripts/train_mix_data.sh  # MIX_SCHEDULE: the mix runs' schedule, the same string they run
. scripts/train_resume.sh  # fit_chunks
SETS="$MIX_SCHEDULE --set train.checkpoint_minutes=0 ${SETS_EXTRA:-}"
if [ "$START" = shipped ]; then FIRST="--init shipped"; else FIRST="--resume $START"; fi
# shellcheck disable=SC2086
fit_chunks "$FIRST" --cache "$CACHE/worlds_train" ${MORE:-}
