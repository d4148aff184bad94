#!/bin/sh
# The second sensor-mix run (MODEL.md, "The sensor mix"): fine-tunes the shipped model on the world's sensors
# while keeping the HDL-64E car on the road where it is. The first run (scripts/train_mix.sh) drew pairs by
# count: its handheld, legged and wheeled drives move slowly (median pair 0.8 m apart, against 1.8 m on the
# roads) and outnumber the roads 8:1 in pairs, and the network learnt to shorten translations (HDL-64E road
# pairs 4.7 m apart: 1.0-1.3 m short, against 0.3-0.9 m for the shipped model). Here every drive weighs the
# same and a drive's pairs are drawn uniform in distance (train.pair_balance=distance), half the mix's drives
# (128: the roads a third of the draws), lr 5e-5 halved every 3 epochs of 100 steps, validation every 200
# steps on both folders (mix, HDL-64E roads), each weighing the same in the choice of model_best.pt.
# The run is scripts/train_mix_balanced.sh on the mix's cache (scripts/train_mix.sh's draws, fewer drives).
# Resumable: run it again after a stop; it continues from runs/mix_keep/state_latest.pt, else from the
# committed deepbbs_ros/models/train_state/mix_keep/state_latest.pt, else from the shipped model.
#   UNTIL=07:35 setsid nohup nice -n 10 scripts/train_mix_keep.sh > runs/mix_keep.log 2>&1 &
#   scripts/train_mix_keep.sh --save-state     # commit the state after a stop
# BUDGET, UNTIL, THREADS, DRIVES: as scripts/train_mix_balanced.sh says.
set -eu
NAME=${NAME:-mix_keep} MIX_DATA=${MIX_DATA:-mix} exec "$(dirname "$0")/train_mix_balanced.sh" "$@"
