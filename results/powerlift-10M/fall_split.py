"""Is an action's loss to tanh(mu) in the starts where its robot fell, or spread over all of them?

    .venv/bin/python results/powerlift-10M/fall_split.py results/powerlift-10M/robust-5M [ACTION]

Per seed, the paired return differences of ACTION (default: mode) against tanh(mu) from the same
start, as `per_seed.csv`'s, split four ways by how the two episodes from that start ended:
neither robot fell, only the action's, only tanh(mu)'s, both. Printed as the README's table rows:
each part's starts, and the mean difference over them +- the standard error of those differences.
A part is chosen by the episodes' own outcomes, so "only the action's fell" is a loss by
construction; what the split tells is whether the starts where neither fell are level, i.e.
whether the falls carry the whole difference.
"""

import csv
import re
import statistics
import sys
from pathlib import Path


def cell(values: list[float]) -> str:
    if len(values) < 2:
        return f"{len(values)}" + (f", {values[0]:+.2f}" if values else "")
    se = statistics.stdev(values) / len(values) ** 0.5
    return f"{len(values)}, {statistics.fmean(values):+.2f} +- {se:.2f}"


folder, action = Path(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else "mode"
for episodes in sorted(folder.glob("*/episodes.csv")):
    with episodes.open() as file:
        rows = {(row["selector"], row["episode"]): row for row in csv.DictReader(file)}
    parts: dict[tuple[bool, bool], list[float]] = {
        (False, False): [],
        (True, False): [],
        (False, True): [],
        (True, True): [],
    }
    steps = set()
    for (name, episode), row in rows.items():
        if name == action:
            base = rows["tanh_mu", episode]
            ends = (row["end"] == "fell", base["end"] == "fell")
            parts[ends].append(float(row["return"]) - float(base["return"]))
            steps.add(int(row["step"]))
    seed = re.search(r"seed(\d+)", episodes.parent.name).group(1)
    step = "/".join(f"{s / 1e6:g}M" for s in sorted(steps))
    print(f"| {seed} | {step} | " + " | ".join(cell(v) for v in parts.values()) + " |")
