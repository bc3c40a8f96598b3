#!/bin/bash
# End of a session: stop this campaign's runs with a checkpoint at their current step, then copy
# what lets each go on without this machine into the checkout: the CSVs, config.json,
# sweep_run.json, the 1M snapshots and, where a run is 500,000 steps or more past its newest
# committed snapshot, one made from the checkpoint (`sweep.py restart` continues from it if the
# checkpoint is lost with the machine); then rebuild the report from reports.json.
# `stop.sh --checkpoint-only`: only the stop, for a session's last minutes after its commit.
# Paths are this machine's: run as a copy, ~/campaign/notes/stop-hb.sh.
set -u
GAP=500000  # a lost machine costs a run at most this many steps; each stop snapshot is 1.6 MB
CAMPAIGN=~/campaign/cube-hb-scene
R=results/cube-hb-scene
OUT=/work/main/$R/runs
pids=$(pgrep -f "campaign/hbsrc/sac_corrected.py" || true)
[ -n "$pids" ] && kill -TERM $pids
for p in $pids; do while kill -0 $p 2>/dev/null; do sleep 1; done; done
[ "${1:-}" = --checkpoint-only ] && { echo "stopped: $pids"; exit 0; }
for config in $CAMPAIGN/*/config.json; do
  [ -e "$config" ] || continue
  d=$(dirname $config)/; r=$(basename $d); mkdir -p $OUT/$r/snapshots
  cp $d/config.json $d/train.csv $d/eval.csv $d/sweep_run.json $OUT/$r/
  [ -d $d/restarts ] && cp -r $d/restarts $OUT/$r/
  [ -d $d/snapshots ] && cp $d/snapshots/*.pt $OUT/$r/snapshots/ 2>/dev/null
  if [ -e $d/done.json ]; then
    cp $d/final_model.pt $d/done.json $OUT/$r/; echo "$r finished"; continue
  fi
  # A snapshot the checkout has and the run has not is an earlier stop's: it gives way to this
  # stop's, or to a newer 1M snapshot; it stays where the run has not gone GAP steps past it.
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
cd /work/main && .venv/bin/python analyze.py $R/runs --out $R/report \
  $(python3 -c "import json; print(' '.join(json.load(open('$R/reports.json'))['report']['args']))") \
  > /tmp/cube-hb-scene-report.log 2>&1 && echo "report rebuilt" || echo "report FAILED: /tmp/cube-hb-scene-report.log"
