#!/usr/bin/env bash
# One million's robust evaluation of powerlift's two runs (README: "The robust evaluation, million
# by million"): wait until every run on this machine has written snapshots/step<N>.pt, copy them
# into the checkout's runs/, pause the training runs (SIGSTOP), evaluate from 100 starts per seed
# (300 at 10M) on both cores into robust-<N/1M>M/, and resume the runs (SIGCONT).
#   setsid nohup results/powerlift-10M/evaluate_million.sh 4000000 > ~/campaign/eval-4M.log 2>&1 &
# `evaluate_million.sh N --finished`, for the last million: evaluate now, without waiting or
# pausing, the runs that have finished (done.json) at step N, on the cores no run trains on; the
# plain command later evaluates the others into the same folder (evaluate.py resumes an --out a
# policy at a time, and its episodes do not depend on --workers).
# EVALUATE: the evaluate.py to run, best a copy pinned at one commit (a `git worktree`), so that
# edits to the checkout while it waits cannot reach it; CAMPAIGN: the runs' folder.
set -u
N=$1; MILLIONS=$((N / 1000000)); EPISODES=$([ "$N" -ge 10000000 ] && echo 300 || echo 100)
CAMPAIGN=${CAMPAIGN:-~/campaign/powerlift-10M}; EVALUATE=${EVALUATE:-evaluate.py}
MAIN=$(cd "$(dirname "$0")/../.." && pwd); R=results/powerlift-10M
copy() {  # run folder on the machine -> its step N snapshot in the checkout's runs/
  run=$(basename "$1"); mkdir -p "$MAIN/$R/runs/$run/snapshots"
  cp "$1/snapshots/step$N.pt" "$MAIN/$R/runs/$run/snapshots/"
}
evaluate() {  # workers
  cd "$MAIN" && .venv/bin/python "$EVALUATE" $R/runs --out $R/robust-${MILLIONS}M \
    --steps $N --reset-noise 0.01 --episodes $EPISODES \
    --selectors mode tanh_mu mean q_best --workers "$1" --reps 20000
}
training() { pgrep -f "campaign/src/sac_corrected.py" | tr '\n' ' '; }
if [ "${2:-}" = --finished ]; then
  for r in "$CAMPAIGN"/*/; do
    [ -e "$r/done.json" ] && [ -e "$r/snapshots/step$N.pt" ] && copy "$r"
  done
  workers=$(( $(nproc) - $(training | wc -w) ))
  [ $workers -ge 1 ] || { echo "no core free: every core trains a run"; exit 1; }
  evaluate $workers; exit
fi
# snapshots are written whole (renamed into place), so one that is there is complete
RUNS=$(ls -d "$CAMPAIGN"/*/ | wc -l)
until [ "$(ls "$CAMPAIGN"/*/snapshots/step$N.pt 2>/dev/null | wc -l)" -ge "$RUNS" ]; do sleep 60; done
for r in "$CAMPAIGN"/*/; do copy "$r"; done
pids=$(training)  # none, once every run has finished
echo "$(date -u) pausing ${pids:-no run}"; [ -z "$pids" ] || kill -STOP $pids
evaluate 2
rc=$?  # read before any other command: $(date) would overwrite it
echo "$(date -u) evaluate.py exited with $rc; resuming ${pids:-no run}"; [ -z "$pids" ] || kill -CONT $pids
