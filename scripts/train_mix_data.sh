# The sensor-mix runs' data, sourced by scripts/train_mix.sh and train_mix_balanced.sh (train_mix_keep.sh,
# train_mix_span.sh; after they set T, CACHE and DRIVES), and train_control.sh (for MIX_SCHEDULE alone).
# Training: DRIVES drives (seeds 20000 and up, two processes) x 25 frames; the scene types
# cycle over the eight places; each drive draws its sensor and mount from its seed: 'random' (the randomised
# spinning road sensors of scripts/train_worlds.sh) twice as often as one preset, Livox Avia and Mid-360 twice too,
# the Ouster / Hesai / RoboSense-like / Velodyne presets once; car twice as often as wheeled, legged or handheld.
# Validation (model selection): 16 drives of the mix (seeds 80100-80115, every sensor preset, mount and place, 30
# frames) and the 8 HDL-64E road drives (80000-80007) the shipped model was selected on. Replay: the 64 road drives
# the shipped model was fine-tuned on (scripts/train_worlds.sh), so that the spinning sensors on car roofs keep
# their share of the training pairs.
# The balanced mix runs' schedule (train_mix_balanced.sh; train_control.sh runs it on the road drives alone): 12
# epochs x 100 steps x batch 8 at 512 points; lr 5e-5 halved every 3 epochs; translation weighted 5x; pairs balanced
# by distance; seed 3. Validation and checkpoints are each script's own.
MIX_SCHEDULE="--set train.epochs=12 --set train.steps_per_epoch=100 --set train.batch_size=8 --set train.lr=5e-5 \
  --set train.pair_balance=distance --set train.lr_step=3 --set train.lr_gamma=0.5 --set train.trans_weight=5 \
  --set train.seed=3 --set train.num_points=512"
SCENES=urban,suburban,highway,open_road,corridor,hall,courtyard,garage
SENSORS=random,random,os0_32,os0_64,os1_64,os1_128,xt32,helios32,vlp16,hdl32,avia,avia,mid360,mid360
MOUNTS=car,car,wheeled,legged,handheld

# mix_train NAME [cache options]: the DRIVES mix training drives in $CACHE/NAME_train (two processes)
mix_train() {
  name=$1
  shift
  half=$((20000 + DRIVES / 2))
  for seeds in "20000:$half" "$half:$((20000 + DRIVES))"; do
    $T cache --out "$CACHE/${name}_train" --split train --seeds "$seeds" --frames 25 --cache-points 4096 \
      --scenes $SCENES --sensors $SENSORS --mounts $MOUNTS "$@" --no-progress --threads 1 &
  done
  wait
}

# road_train: the 64 road drives the shipped model was fine-tuned on, $CACHE/worlds_train (two processes)
road_train() {
  for seeds in 10000:10032 10032:10064; do
    $T cache --out "$CACHE/worlds_train" --split train --seeds "$seeds" --frames 25 --cache-points 4096 \
      --no-progress --threads 1 &
  done
  wait
}

# mix_val NAME [cache options]: the 16 mix validation drives in $CACHE/NAME_val
mix_val() {
  name=$1
  shift
  $T cache --out "$CACHE/${name}_val" --split val --seeds 80100:80116 --frames 30 --cache-points 4096 \
    --scenes $SCENES --sensors os0_32,os0_64,os1_64,os1_128,xt32,helios32,vlp16,hdl32,avia,mid360 \
    --mounts car,wheeled,legged,handheld "$@" --no-progress --threads 1
}

# road_val: the 8 HDL-64E road validation drives in $CACHE/worlds_val
road_val() {
  $T cache --out "$CACHE/worlds_val" --split val --drives 8 --frames 30 --cache-points 4096 --no-progress --threads 1
}

# mix_data NAME [cache options for the mix drives]: $CACHE/NAME_train, $CACHE/NAME_val, the road folders
mix_data() {
  mix_train "$@"
  mix_val "$@" &
  a=$!
  road_val &
  wait "$a" $!
  road_train
}
