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

# 1. data. Training: DRIVES drives (seeds 20000 and up, two processes) x 25 frames; the scene types cycle
#    over the eight places; each drive draws its sensor and mount from its seed: 'random' (the randomised
#    spinning road sensors of scripts/train_worlds.sh) twice as often as one preset, Livox Avia and Mid-360
#    twice too, the Ouster / Hesai / RoboSense-like / Velodyne presets once; car twice as often as wheeled,
#    legged or handheld. Validation (model selection): 16 drives of the mix (seeds 80100-80115, every
#    sensor preset, mount and place, 30 frames) and the 8 HDL-64E road drives (80000-80007) the shipped model
#    was selected on.
SCENES=urban,suburban,highway,open_road,corridor,hall,courtyard,garage
SENSORS=random,random,os0_32,os0_64,os1_64,os1_128,xt32,helios32,vlp16,hdl32,avia,avia,mid360,mid360
MOUNTS=car,car,wheeled,legged,handheld
HALF=$((20000 + DRIVES / 2))
$T cache --out "$CACHE/mix_train" --split train --seeds "20000:$HALF" --frames 25 --cache-points 4096 \
  --scenes $SCENES --sensors $SENSORS --mounts $MOUNTS --no-progress --threads 1 &
$T cache --out "$CACHE/mix_train" --split train --seeds "$HALF:$((20000 + DRIVES))" --frames 25 --cache-points 4096 \
  --scenes $SCENES --sensors $SENSORS --mounts $MOUNTS --no-progress --threads 1 &
wait
$T cache --out "$CACHE/mix_val" --split val --seeds 80100:80116 --frames 30 --cache-points 4096 --scenes $SCENES \
  --sensors os0_32,os0_64,os1_64,os1_128,xt32,helios32,vlp16,hdl32,avia,mid360 --mounts car,wheeled,legged,handheld \
  --no-progress --threads 1
$T cache --out "$CACHE/worlds_val" --split val --drives 8 --frames 30 --cache-points 4096 --no-progress --threads 1
# replay: the 64 road drives the shipped model was fine-tuned on (scripts/train_worlds.sh), so that the
# spinning sensors on car roofs keep their share (about a fifth of the training pairs)
$T cache --out "$CACHE/worlds_train" --split train --seeds 10000:10064 --frames 25 --cache-points 4096 \
  --no-progress --threads 1

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
