#!/bin/sh
# Ship the best checkpoint of a training run as the package's default model, with its evidence:
#   scripts/ship_model.sh [RUN] [DRIVES_PER_SCENE]     (defaults: runs/default, 4)
# Copies RUN/model_best.pt -> deepbbs_ros/models/deepbbspp_lidar.pt, the validation history and the
# curves next to it, then evaluates the shipped file on the held-out test seeds (90000 + i) and writes
# deepbbs_ros/models/deepbbspp_lidar_metrics.{json,md} (MODEL.md cites them).
set -eu
cd "$(dirname "$0")/.."
RUN=${1:-runs/default}
DRIVES=${2:-4}
PY=${PY:-.venv/bin/python}
THREADS=${THREADS:-0}
M=deepbbs_ros/models
cp "$RUN/model_best.pt" "$M/deepbbspp_lidar.pt"
cp "$RUN/val.csv" "$M/deepbbspp_lidar_val.csv"
cp "$RUN/curves.png" "$M/deepbbspp_lidar_curves.png"
$PY -m deepbbs_ros.cli.train report --run "$RUN" > "$M/deepbbspp_lidar_training.md"
cat "$M/deepbbspp_lidar_training.md"
$PY -m deepbbs_ros.cli.train evaluate --weights "$M/deepbbspp_lidar.pt" --drives-per-scene "$DRIVES" --frames 60 \
  --stride 10 --yaw-deg 45 --threads "$THREADS" --no-progress \
  --out "$M/deepbbspp_lidar_metrics.json" --markdown "$M/deepbbspp_lidar_metrics.md"
ls -la "$M"
