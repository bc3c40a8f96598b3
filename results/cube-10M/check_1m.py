"""Do the 10M runs' first 1M steps reproduce the published 1M runs of their seeds?

    .venv/bin/python results/cube-10M/check_1m.py [CAMPAIGN_DIR]   # default ~/campaign/cube-10M

train.csv row by row to 1M (every column but wall_time and sps), and the 1M snapshot's actor and
critic tensors against final_model.pt (which carries a leading seed axis of 1, from the
--num-seeds era), with torch.equal.
"""

import csv
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
campaign = Path(sys.argv[1]) if len(sys.argv) > 1 else Path.home() / "campaign/cube-10M"
published = ROOT / "results/cube-1M/runs"


def rows(path: Path) -> dict[int, dict]:
    with path.open() as file:
        return {int(row["global_step"]): row for row in csv.DictReader(file)}


for seed in (2, 3):
    new, old = next(campaign.glob(f"*seed{seed}__*")), next(published.glob(f"*seed{seed}__*"))
    a, b = rows(old / "train.csv"), rows(new / "train.csv")
    shared = sorted(set(a) & set(b))
    differ = [(s, c) for s in shared for c in a[s] if c not in ("wall_time", "sps")
              and a[s][c] != b[s].get(c)]
    print(f"seed {seed}: train.csv {len(shared)} shared rows (to {max(shared):,}), "
          f"{len(differ)} mismatches {differ[:3]}")
    snapshot = new / "snapshots/step1000000.pt"
    if not snapshot.exists():
        print("  no 1M snapshot yet")
        continue
    s = torch.load(snapshot, map_location="cpu", weights_only=False)
    f = torch.load(old / "final_model.pt", map_location="cpu", weights_only=False)
    pairs = [(t, f[part][k].reshape(t.shape)) for part in ("actor", "qf")
             for k, t in s[part].items()]
    print(f"  {sum(torch.equal(x, y) for x, y in pairs)} of {len(pairs)} actor and critic "
          "tensors bitwise equal")
