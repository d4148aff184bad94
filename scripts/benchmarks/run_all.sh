#!/usr/bin/env bash
# Every benchmark behind docs/benchmarks.md, in a fixed order, into one folder, then a summary of the figures.
#
#   scripts/benchmarks/run_all.sh --kitti PATH/TO/kitti/00 --kitti PATH/TO/kitti/02 [--pair PATH/TO/pair] [--out DIR]
#       [--cache DIR] [--nuscenes PATH/TO/nuscenes_hdl32] [--livox PATH/TO/livox_avia_loop]
#
# --kitti: a KITTI odometry sequence folder (velodyne/, poses.txt, calib.txt), repeatable; the benchmarks read
# its first 10 scans. --pair: optional folder of a real reference pair (two .pcd files, target and source in
# name order, and relative.txt). --nuscenes, --livox: optional real scans of other LiDARs in the KITTI layout for
# families.py (its --help). --cache: the localization benchmark's generated maps and queries (default
# ~/.cache/deepbbs_ros/bench; made once). --out: results folder (default results/benchmarks/<UTC time>). Each benchmark
# writes its JSON and PNG there (the node latency runs into sub-folders) and its log under logs/; a failing
# one is reported and the others still run (exit code 1 at the end). Run it with nothing else on the computer:
# the speed figures are wall-clock. PY selects the interpreter (default: .venv/bin/python, else python3).
set -u
cd "$(dirname "$0")/../.."
KITTI=()
PAIR=()
FAMILIES=()
OUT="results/benchmarks/$(date -u +%Y-%m-%d_%H-%M-%S)"
CACHE="${XDG_CACHE_HOME:-$HOME/.cache}/deepbbs_ros/bench"
while [ $# -gt 0 ]; do
  case "$1" in
    --kitti) KITTI+=("$2"); shift 2 ;;
    --pair) PAIR=(--pair "$2"); shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    --cache) CACHE="$2"; shift 2 ;;
    --nuscenes|--livox) FAMILIES+=("$1" "$2"); shift 2 ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) echo "run_all.sh: unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
if [ ${#KITTI[@]} -eq 0 ]; then
  echo "run_all.sh: give at least one --kitti PATH/TO/kitti/NN (see --help)" >&2
  exit 2
fi
if [ -z "${PY:-}" ]; then
  if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
mkdir -p "$OUT/logs"
B=scripts/benchmarks
FAILED=()
STEPS=()

step() {  # step NAME COMMAND...: run it, log it, time it
  local name=$1
  shift
  echo "== $name: $*"
  local t0=$SECONDS
  echo "${*:2}" > "$OUT/logs/$name.command"  # the command, as the JSON files record theirs (render_docs.py)
  if "$@" > "$OUT/logs/$name.log" 2>&1; then status=ok; else status="FAILED ($?)"; FAILED+=("$name"); fi
  STEPS+=("$name: $status, $((SECONDS - t0)) s")
  echo "   $status in $((SECONDS - t0)) s (log: $OUT/logs/$name.log)"
}

machine() {  # machine NAME: the machine entry the JSON files carry, for a benchmark that writes none (runs.jsonl)
  $PY -c "import json, sys; sys.path.insert(0, '$B'); import _common; print(json.dumps(_common.machine()))" \
    > "$OUT/logs/$1.machine.json" 2>/dev/null
}

step decode $PY $B/decode.py --runs 500 --out "$OUT"
step simulator $PY $B/simulator.py --frames 30 --out "$OUT"
step registration $PY $B/registration.py --kitti "${KITTI[@]}" "${PAIR[@]}" --out "$OUT"
step good_start $PY $B/good_start.py --kitti "${KITTI[@]}" --out "$OUT"
step families $PY $B/families.py --quick --kitti "${KITTI[@]}" "${PAIR[@]}" "${FAMILIES[@]}" --cache "$CACHE" --out "$OUT"
step deskew $PY $B/deskew.py --drives-per-scene 1 --threads 1 --out "$OUT"
step odometry $PY $B/odometry.py --frames 500 --kitti "${KITTI[@]}" --out "$OUT"
step busy $PY $B/busy.py --kitti "${KITTI[@]}" --rounds 1 --policies passive,default --out "$OUT"
step first_contact $PY $B/first_contact.py --runs 3 --out "$OUT"
step node_latency_odometry $PY $B/node_latency.py --mode odometry --layout both --seconds 10 \
  --out "$OUT/node_latency_odometry"
machine node_latency_odometry
step node_latency_pair $PY $B/node_latency.py --data kitti --kitti "${KITTI[@]}" --mode pair --stream both \
  --layout velodyne --runs 2 --seconds 10 --out "$OUT/node_latency_pair"
machine node_latency_pair
step node_latency_localization $PY $B/node_latency.py --mode localization --layout velodyne --scans 200 --runs 2 \
  --seconds 10 --out "$OUT/node_latency_localization"
machine node_latency_localization
step localization $PY $B/localization.py --kitti "${KITTI[@]}" "${PAIR[@]}" --cache "$CACHE" --out "$OUT"
step kidnap $PY $B/kidnap.py --out "$OUT"
step fleet $PY $B/fleet.py --recordings 4 --frames 20 --workers 1,2 --out "$OUT"
step threads $PY $B/threads.py bags/urban_drive_hdl64 --rounds 3 --out "$OUT"
cp "$OUT/node_latency_odometry/latency.png" "$OUT/node_latency_odometry.png" 2>/dev/null
cp "$OUT/node_latency_pair/latency.png" "$OUT/node_latency_pair.png" 2>/dev/null
cp "$OUT/node_latency_localization/latency.png" "$OUT/node_latency_localization.png" 2>/dev/null

echo
printf '%s\n' "${STEPS[@]}"
$PY $B/_summary.py "$OUT"
echo
echo "docs/benchmarks.md and the README's Results table: $PY $B/render_docs.py $OUT --copy"
if [ ${#FAILED[@]} -gt 0 ]; then
  echo "failed: ${FAILED[*]}" >&2
  exit 1
fi
