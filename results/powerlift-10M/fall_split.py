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
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from analysis.estimators import BASELINE, paired_difference, standard_error  # noqa: E402


def cell(values: list[float]) -> str:
    if len(values) < 2:
        return f"{len(values)}" + (f", {values[0]:+.2f}" if values else "")
    return f"{len(values)}, {np.mean(values):+.2f} +- {standard_error(values):.2f}"


if len(sys.argv) not in (2, 3):
    sys.exit("usage: fall_split.py FOLDER [ACTION]  (a folder evaluate.py wrote: "
             "results/powerlift-10M/robust-5M)")
folder, action = Path(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else "mode"
if not (folder / "evaluation.json").is_file():
    sys.exit(f"fall_split.py: no evaluation.json in {folder}: give a folder evaluate.py wrote")
for run, about in json.loads((folder / "evaluation.json").read_text())["runs"].items():
    episodes = folder / run / "episodes.csv"
    with episodes.open() as file:
        rows = {(r["step"], r["selector"], r["episode"]): r for r in csv.DictReader(file)}
    selectors = {name for _, name, _ in rows}
    if action not in selectors or BASELINE not in selectors:
        sys.exit(
            f"fall_split.py: {episodes} has actions {sorted(selectors)}; it needs {action} "
            f"and {BASELINE}"
        )
    if not next(iter(rows.values())).get("end"):
        sys.exit(
            f"fall_split.py: {episodes} does not record how episodes ended (no 'end' "
            "column): re-run evaluate.py on it"
        )
    for step in sorted({int(s) for s, _, _ in rows}):
        pairs = [
            (row, rows[at, BASELINE, episode])
            for (at, name, episode), row in rows.items()
            if int(at) == step and name == action
        ]
        differences = paired_difference(
            [float(it["return"]) for it, _ in pairs], [float(base["return"]) for _, base in pairs]
        )
        parts: dict[tuple[bool, bool], list[float]] = {
            (False, False): [],
            (True, False): [],
            (False, True): [],
            (True, True): [],
        }
        for (it, base), difference in zip(pairs, differences, strict=True):
            parts[it["end"] == "fell", base["end"] == "fell"].append(difference)
        cells = " | ".join(cell(values) for values in parts.values())
        print(f"| {about['seed']} | {step / 1e6:g}M | {cells} |")
