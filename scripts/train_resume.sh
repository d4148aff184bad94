# Sourced by scripts/train_worlds.sh and scripts/train_mix.sh: the resume, initialisation and budget
# logic the resumable training scripts share. Needs RUN (the run folder), STATE (the committed state
# folder) and BUDGET (minutes of fitting this invocation, 0 = until the schedule ends).

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
