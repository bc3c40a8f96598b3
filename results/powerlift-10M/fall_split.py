"""Is an action's loss to tanh(mu) in the starts where its robot fell, or spread over all of them?

    .venv/bin/python results/powerlift-10M/fall_split.py results/powerlift-10M/robust-4M [ACTION...]

Per seed and action (default: mode), the paired return differences (the action minus tanh(mu)
from the same start, as `per_seed.csv`'s) split four ways by how the two episodes from that start
ended: neither robot fell, only the action's, only tanh(mu)'s, both; each part's count and mean
+- the standard error of its differences. A part is chosen by the episodes' own outcomes, so
"only the action's fell" is a loss by construction; what the split tells is whether the starts
where neither fell are level, i.e. whether the falls carry the whole difference.
"""

import csv
import statistics
import sys
from pathlib import Path


def mean_se(values: list[float]) -> str:
    if len(values) < 2:
        return f"{values[0]:+.2f}" if values else "-"
    return f"{statistics.fmean(values):+.2f} +- {statistics.stdev(values) / len(values) ** 0.5:.2f}"


folder, actions = Path(sys.argv[1]), sys.argv[2:] or ["mode"]
for episodes in sorted(folder.glob("*/episodes.csv")):
    with episodes.open() as file:
        rows = {(row["selector"], row["episode"]): row for row in csv.DictReader(file)}
    for action in actions:
        parts: dict[str, list[float]] = {
            "neither": [],
            "only it": [],
            "only tanh_mu": [],
            "both": [],
        }
        for (name, episode), row in rows.items():
            if name != action:
                continue
            base = rows["tanh_mu", episode]
            it, them = row["end"] == "fell", base["end"] == "fell"
            part = (
                ("both" if them else "only it") if it else ("only tanh_mu" if them else "neither")
            )
            parts[part].append(float(row["return"]) - float(base["return"]))
        cells = "; ".join(f"{p} fell: {len(v)}, {mean_se(v)}" for p, v in parts.items())
        print(f"{episodes.parent.name} {action} - tanh_mu: {cells}")
