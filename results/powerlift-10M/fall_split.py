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


if len(sys.argv) not in (2, 3):
    sys.exit("usage: fall_split.py ROBUST_FOLDER [ACTION]  (a folder evaluate.py wrote; see above)")
folder, action = Path(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else "mode"
found = sorted(folder.glob("*/episodes.csv"))
if not found:
    sys.exit(f"fall_split.py: no <run>/episodes.csv in {folder}: give a folder evaluate.py wrote")
for episodes in found:
    with episodes.open() as file:
        rows = {(r["step"], r["selector"], r["episode"]): r for r in csv.DictReader(file)}
    selectors = {name for _, name, _ in rows}
    if action not in selectors or "tanh_mu" not in selectors:
        sys.exit(
            f"fall_split.py: {episodes} has actions {sorted(selectors)}; it needs {action} "
            "and tanh_mu"
        )
    if "end" not in next(iter(rows.values())):
        sys.exit(
            f"fall_split.py: {episodes} does not record how episodes ended (no 'end' "
            "column): re-run evaluate.py on it"
        )
    seed = re.search(r"seed(\d+)", episodes.parent.name).group(1)
    for step in sorted({int(s) for s, _, _ in rows}):
        parts: dict[tuple[bool, bool], list[float]] = {
            (False, False): [],
            (True, False): [],
            (False, True): [],
            (True, True): [],
        }
        for (at, name, episode), row in rows.items():
            if int(at) == step and name == action:
                base = rows[at, "tanh_mu", episode]
                ends = (row["end"] == "fell", base["end"] == "fell")
                parts[ends].append(float(row["return"]) - float(base["return"]))
        cells = " | ".join(cell(values) for values in parts.values())
        print(f"| {seed} | {step / 1e6:g}M | {cells} |")
