#!/bin/sh
# The third sensor-mix run (MODEL.md, "The sensor mix"): scripts/train_mix_keep.sh with the mix drives' frames
# spread over 10 m of travel. At 10 Hz, 25 consecutive sweeps of a handheld, legged or wheeled drive (0.5-1.5 m/s)
# travel 1-3 m: those drives had no pair farther apart than that, though the registration is asked (and evaluated)
# up to train.max_dist (5 m). `deepbbs-train cache --min-span 10` keeps every s-th sweep of a drive (s the smallest
# stride, at most 10, whose 25 frames travel 10 m: 2-8 for the slow mounts, 1-2 for a car), so every drive has
# pairs from 0 to 5 m and `train.pair_balance: distance` draws them uniform in distance. The road replay and the
# HDL-64E validation drives are those of the other runs; everything else (seeds, sensors, mounts, places,
# schedule) is scripts/train_mix_keep.sh's: both are scripts/train_mix_balanced.sh.
# Resumable: run it again after a stop; it continues from runs/mix_span/state_latest.pt, else from the
# committed deepbbs_ros/models/train_state/mix_span/state_latest.pt, else from the shipped model.
#   UNTIL=10:30 setsid nohup nice -n 10 scripts/train_mix_span.sh > runs/mix_span.log 2>&1 &
#   scripts/train_mix_span.sh --save-state     # commit the state after a stop
# The fourth run (the bounded per-pair pose loss, train.pose_loss=bounded) is this script with its own run and
# state folders:
#   NAME=mix_bound POSE_LOSS=bounded UNTIL=13:25 setsid nohup nice -n 10 scripts/train_mix_span.sh > runs/mix_bound.log 2>&1 &
#   NAME=mix_bound scripts/train_mix_span.sh --save-state
# NAME: run and state folder name (runs/NAME, deepbbs_ros/models/train_state/NAME). POSE_LOSS: train.pose_loss.
# BUDGET, UNTIL, THREADS, DRIVES: as scripts/train_mix_balanced.sh says.
set -eu
NAME=${NAME:-mix_span} MIX_DATA=${MIX_DATA:-mix_span --min-span 10} exec "$(dirname "$0")/train_mix_balanced.sh" "$@"
