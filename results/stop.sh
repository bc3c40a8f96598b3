#!/bin/bash
# End of a session, for every campaign of results/: stop the runs that the clone SRC launched,
# with a checkpoint at their current step, then copy what lets each run of each CAMPAIGN folder
# (~/campaign/<name>, whose results/<name>/runs/ holds its copy) go on without this machine into
# the checkout: the CSVs, config.json, sweep_run.json, the run's own snapshots and, where the run
# is GAP steps or more past its newest snapshot there (500,000 unless GAP says), one made from
# the checkpoint (`sweep.py restart` continues from it if the checkpoint is lost). A finished run
# (done.json) is copied whole: its final_model.pt and done.json, no stop snapshot, and no snapshot
# at its last step (the final weights); one finished at an earlier stop is left as it is in the
# checkout. Then each campaign's report is rebuilt from its reports.json where a run's CSVs
# changed.
#
#   results/stop.sh [--checkpoint-only] SRC CAMPAIGN...
#   e.g. GAP=1 results/stop.sh ~/campaign/hbsrc ~/campaign/cube-hb-scene
#        results/stop.sh ~/campaign/src ~/campaign/cube-10M ~/campaign/powerlift-10M
#
# --checkpoint-only: only the stop, for a session's last minutes after its commit, so that a kept
# machine resumes from where the runs were (nothing is copied). Run it as a copy outside the
# checkout (~/campaign/notes/stop.sh), as bash reads a script while it runs; CHECKOUT (default
# /work/main) is the checkout with its .venv.
set -u
# A lost machine costs a run at most GAP steps (and a restart's refill); each stop snapshot of a
# 61-actuator run is 1.6 MB, in git's history for good, so a campaign's last stretch may lower it.
GAP=${GAP:-500000}
CHECKOUT=${CHECKOUT:-/work/main}
only=0; [ "${1:-}" = --checkpoint-only ] && { only=1; shift; }
[ $# -ge 2 ] || { echo "usage: stop.sh [--checkpoint-only] SRC CAMPAIGN... (SRC: the clone the runs were launched from)"; exit 2; }
src=$(realpath "$1"); shift
# The sweep launched from SRC first (its working directory: its command line names no path),
# or it launches the next runs as soon as these stop.
for p in $(pgrep -f "sweep.py" || true); do
  [ "$(readlink /proc/$p/cwd)" = "$src" ] && kill -KILL $p
done
pids=$(pgrep -f "$src/sac_(standard|corrected).py" || true)
[ -n "$pids" ] && kill -TERM $pids
for p in $pids; do while kill -0 $p 2>/dev/null; do sleep 1; done; done
[ $only = 1 ] && { echo "stopped:" $pids; exit 0; }
for campaign in "$@"; do
  task=$(basename $campaign); R=results/$task; OUT=$CHECKOUT/$R/runs; changed=0
  # a sweep's run not started yet: its sweep_run.json, so that evaluate.py keeps the campaign's
  # evaluations open for it and a new machine's sweep launches it
  for plan in $campaign/*/sweep_run.json; do
    [ -e "$plan" ] && [ ! -e $(dirname $plan)/config.json ] || continue
    mkdir -p $OUT/$(basename $(dirname $plan)) && cp $plan $OUT/$(basename $(dirname $plan))/
  done
  for config in $campaign/*/config.json; do
    [ -e "$config" ] || continue
    d=$(dirname $config); r=$(basename $d)
    # finished at an earlier stop: as committed (its evaluated snapshots may have left the tree)
    [ -e $d/done.json ] && cmp -s $d/done.json $OUT/$r/done.json && continue
    mkdir -p $OUT/$r/snapshots
    cmp -s $d/train.csv $OUT/$r/train.csv && cmp -s $d/eval.csv $OUT/$r/eval.csv || changed=1
    cp $d/config.json $d/train.csv $d/eval.csv $d/sweep_run.json $OUT/$r/
    # a restart from a snapshot keeps the CSVs as they were in restarts/step<N>/
    [ -d $d/restarts ] && cp -r $d/restarts $OUT/$r/
    [ -d $d/snapshots ] && cp $d/snapshots/*.pt $OUT/$r/snapshots/ 2>/dev/null
    if [ -e $d/done.json ]; then
      # an earlier stop's snapshot (one the run has not) is not needed once the run is done, nor
      # the one at its last step: final_model.pt holds the same weights (and evaluate.py reads it)
      last=$(python3 -c "import json; print(json.load(open('$d/done.json'))['global_step'])")
      for f in $OUT/$r/snapshots/*.pt; do
        [ -e $d/snapshots/$(basename $f) ] && [ $(basename $f) != step$last.pt ] || rm -f $f
      done
      cp $d/final_model.pt $d/done.json $OUT/$r/; echo "$r finished"; continue
    fi
    # The run's own snapshots (the 1M grid, a restart's) are copied above; one the checkout has
    # and the run has not is an earlier stop's. It gives way to this stop's snapshot, or to a
    # newer grid snapshot; it stays where the run has not gone GAP steps past it.
    (cd $CHECKOUT && .venv/bin/python - $d $OUT/$r/snapshots $GAP <<'PY'
import sys
from pathlib import Path

from sac_utils.checkpoints import read_checkpoint
from sac_utils.restart import snapshot_from_checkpoint

run, out, gap = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
def step(p: Path) -> int:
    return int(p.stem.removeprefix("step"))
own = {p.name for p in (run / "snapshots").glob("step*.pt")}
stops = [p for p in out.glob("step*.pt") if p.name not in own]
newest = max((step(p) for p in out.glob("step*.pt")), default=0)
at = read_checkpoint(run / "checkpoint.pt")["global_step"]
if at - newest >= gap:
    snapshot_from_checkpoint(run, out)
    print(run.name, "stopped at", at, f"snapshot step{at}.pt")
    keep = at
else:
    print(run.name, "stopped at", at, f"no snapshot: {at - newest:,} steps past step{newest}.pt")
    keep = newest
for p in stops:
    if step(p) != keep:
        p.unlink()
PY
    )
  done
  # The report reads the runs' CSVs, which grew: rebuild it with reports.json's flags
  # (tests/test_results.py checks it against the committed runs). Paths relative to the
  # checkout, as the README's command gives them, so that summary.md names no machine's folders.
  [ -e $CHECKOUT/$R/reports.json ] && [ $changed = 1 ] || continue
  (cd $CHECKOUT && .venv/bin/python analyze.py $R/runs --out $R/report \
    $(python3 -c "import json; print(' '.join(json.load(open('$R/reports.json'))['report']['args']))") \
    > /tmp/$task-report.log 2>&1) && echo "$task report rebuilt" || echo "$task report FAILED: /tmp/$task-report.log"
  # a campaign's own figures beside published curves (cube-hb-scene's) redraw from the same CSVs
  for figure in $CHECKOUT/$R/beside_*.py; do
    [ -e "$figure" ] && (cd $CHECKOUT && .venv/bin/python $figure) || true
  done
done
