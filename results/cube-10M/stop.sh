#!/bin/bash
# End of a session: stop the campaign's runs with a checkpoint at their current step, then copy
# what lets each go on without this machine into the checkout (CSVs, config, a snapshot made from
# the checkpoint: `sweep.py restart` continues from it if the checkpoint is lost). A finished run
# (done.json) is copied whole: its final_model.pt and done.json, no stop snapshot.
set -u
pids=$(pgrep -f "campaign/src/sac_corrected.py" || true)
[ -n "$pids" ] && kill -TERM $pids
for p in $pids; do while kill -0 $p 2>/dev/null; do sleep 1; done; done
for campaign in ~/campaign/*-10M/; do
  task=$(basename $campaign); OUT=/work/main/results/$task/runs; changed=0
  for config in $campaign*/config.json; do
    [ -e "$config" ] || continue
    d=$(dirname $config)/; r=$(basename $d); mkdir -p $OUT/$r/snapshots
    # an earlier stop's snapshot (off the 1M grid) gives way to this stop's; a restart's comes back
    # with the run's own snapshots below
    for f in $OUT/$r/snapshots/step*.pt; do
      [ -e "$f" ] || continue; n=$(basename $f .pt); n=${n#step}; [ $((n % 1000000)) -ne 0 ] && rm -f $f
    done
    cmp -s $d/train.csv $OUT/$r/train.csv && cmp -s $d/eval.csv $OUT/$r/eval.csv || changed=1
    cp $d/config.json $d/train.csv $d/eval.csv $d/sweep_run.json $OUT/$r/
    # a restart from a snapshot keeps the CSVs as they were in restarts/step<N>/
    [ -d $d/restarts ] && cp -r $d/restarts $OUT/$r/
    [ -d $d/snapshots ] && cp $d/snapshots/*.pt $OUT/$r/snapshots/ 2>/dev/null
    if [ -e $d/done.json ]; then
      cp $d/final_model.pt $d/done.json $OUT/$r/; echo "$r finished"; continue
    fi
    (cd /work/main && .venv/bin/python -c 'import sys; from pathlib import Path
from sac_utils.checkpoints import snapshot_from_checkpoint as snap
print(Path(sys.argv[1]).name, "stopped at", snap(Path(sys.argv[1]), Path(sys.argv[2])))' $d $OUT/$r/snapshots)
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
