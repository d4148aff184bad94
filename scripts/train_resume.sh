# Sourced by scripts/train_worlds.sh, train_mix.sh, train_mix_clean.sh and train_control.sh: the resume,
# initialisation, budget and chunked-fit logic the resumable training scripts share. Needs RUN (the run folder),
# STATE (the committed state folder) and BUDGET (minutes of fitting this invocation, 0 = until the schedule ends);
# fit_chunks needs T, PY, SETS, STEPS, CHUNK and THREADS.

# save_state: copy the run's resume state, best model, validation history, curves, fit arguments and log into $STATE.
save_state() {
  mkdir -p "$STATE"
  for f in state_latest.pt model_best.pt val.csv curves.png config.yaml fit_args.json val_best.json log.jsonl; do
    if [ -f "$RUN/$f" ]; then cp "$RUN/$f" "$STATE/$f"; fi
  done
  if [ -f "$RUN.log" ]; then tail -n 400 "$RUN.log" > "$STATE/train_tail.log"; fi
  ls -la "$STATE"
}

# start_args COMMIT NAME: set START to resume from $RUN, else from the committed $STATE, else to initialise
# from the model shipped at COMMIT (written to $RUN/NAME); set LIMIT from BUDGET.
start_args() {
  mkdir -p "$RUN"
  if [ -f "$RUN/state_latest.pt" ]; then
    START="--resume"
  elif [ -f "$STATE/state_latest.pt" ]; then
    START="--resume $STATE/state_latest.pt"
  else
    git show "$1:deepbbs_ros/models/deepbbspp_lidar.pt" > "$RUN/$2"
    START="--init $RUN/$2"
  fi
  if [ "$BUDGET" != 0 ]; then LIMIT="--time-budget-min $BUDGET"; else LIMIT=""; fi
}

# fit_chunks FIRST FIT_ARGS...: `$T fit FIT_ARGS... --run $RUN ... $SETS`, STEPS steps CHUNK at a time, resuming
# $RUN's state, or starting with FIRST ("--init shipped", "--resume STATE_FILE") while $RUN has none; the weights
# are copied after each chunk to $RUN/stepN.pt. A dry run (PY=echo) prints the fit command once.
fit_chunks() {
  first=$1
  shift
  done_steps=0
  while [ "$done_steps" -lt "$STEPS" ]; do
    if [ -f "$RUN/state_latest.pt" ]; then FROM="--resume"; else FROM=$first; fi
    # shellcheck disable=SC2086
    $T fit "$@" --run "$RUN" --threads "$THREADS" --no-progress $SETS $FROM --max-steps "$CHUNK"
    if [ "$PY" = echo ]; then break; fi
    step=$($PY -c "import torch, sys; print(torch.load(sys.argv[1], weights_only=False)['step'])" "$RUN/state_latest.pt")
    cp "$RUN/model_latest.pt" "$RUN/step$step.pt"
    echo "weights at step $step: $RUN/step$step.pt"
    done_steps=$((done_steps + CHUNK))
  done
}
