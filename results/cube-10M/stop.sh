#!/bin/bash
# End of a session: stop the campaign's runs with a checkpoint at their current step, then copy
# what lets each go on without this machine into the checkout (CSVs, config, and, where the run
# is 500,000 steps or more past its newest snapshot there, a snapshot made from the checkpoint:
# `sweep.py restart` continues from it if the checkpoint is lost). A finished run (done.json) is
# copied whole: its final_model.pt and done.json, no stop snapshot.
# `stop.sh --checkpoint-only`: only the stop, for a session's last minutes after its commit, so
# that a kept machine resumes from where the runs were (nothing is copied).
set -u
GAP=500000  # a lost machine costs a run at most this many steps; each stop snapshot is 1.6 MB
pids=$(pgrep -f "campaign/src/sac_corrected.py" || true)
[ -n "$pids" ] && kill -TERM $pids
for p in $pids; do while kill -0 $p 2>/dev/null; do sleep 1; done; done
[ "${1:-}" = --checkpoint-only ] && { echo "stopped: $pids"; exit 0; }
for campaign in ~/campaign/*-10M/; do
  task=$(basename $campaign); OUT=/work/main/results/$task/runs; changed=0
  for config in $campaign*/config.json; do
    [ -e "$config" ] || continue
    d=$(dirname $config)/; r=$(basename $d); mkdir -p $OUT/$r/snapshots
    cmp -s $d/train.csv $OUT/$r/train.csv && cmp -s $d/eval.csv $OUT/$r/eval.csv || changed=1
    cp $d/config.json $d/train.csv $d/eval.csv $d/sweep_run.json $OUT/$r/
    # a restart from a snapshot keeps the CSVs as they were in restarts/step<N>/
    [ -d $d/restarts ] && cp -r $d/restarts $OUT/$r/
    [ -d $d/snapshots ] && cp $d/snapshots/*.pt $OUT/$r/snapshots/ 2>/dev/null
    if [ -e $d/done.json ]; then
      cp $d/final_model.pt $d/done.json $OUT/$r/; echo "$r finished"; continue
    fi
    # The run's own snapshots (the 1M grid, a restart's) are copied above; one the checkout has
    # and the run has not is an earlier stop's. It gives way to this stop's snapshot, or to a
    # newer grid snapshot; it stays where the run has not gone GAP steps past it.
    (cd /work/main && .venv/bin/python - $d $OUT/$r/snapshots $GAP <<'PY'
import sys
from pathlib import Path

from sac_utils.checkpoints import read_checkpoint, snapshot_from_checkpoint

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
  # (Not when no run's CSVs changed since the last stop: a finished campaign's report stays.)
  R=results/$task
  [ -e /work/main/$R/reports.json ] && [ $changed = 1 ] || continue
  cd /work/main && .venv/bin/python analyze.py $R/runs --out $R/report \
    $(python3 -c "import json; print(' '.join(json.load(open('$R/reports.json'))['report']['args']))") \
    > /tmp/$task-report.log 2>&1 && echo "$task report rebuilt" || echo "$task report FAILED: /tmp/$task-report.log"
done
