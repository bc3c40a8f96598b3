"""The README's per-seed table rows, from an evaluation's per_seed.csv.

    .venv/bin/python results/powerlift-10M/per_seed_rows.py results/powerlift-10M/robust-5M

Per seed and step: tanh(mu)'s mean return +- its standard error; the mode, the mean action and
q_best each minus tanh(mu) from the same starts +- the standard error of the paired episodes,
with the verdict (ahead / behind beyond 3 standard errors, else level) and how many standard
errors from zero; the episodes where the robot fell (the mode's / tanh(mu)'s) with the paired
difference of the shares (more / fewer by the same rule); the episodes that ran to the time limit.
Standard errors from zero get a third digit within 0.1 of the line, where the verdict turns on it.
"""

import csv
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from analysis.estimators import BASELINE, VERDICT_SE, fall_verdict, verdict  # noqa: E402

ACTIONS = ("mode", "mean", "q_best")


def distance(mean: float, se: float) -> str:
    z = abs(mean) / se
    return f"{z:#.3g}" if abs(z - VERDICT_SE) < 0.1 else f"{z:#.2g}".rstrip(".")


def judged(word: str) -> str:
    return word if word == "level" else f"**{word}**"


def difference(mean: float, se: float, digits: int,
               judge: Callable[[float, float], str] = verdict) -> tuple[str, str]:
    word = judge(mean, se)
    return f"{mean:+.{digits}f} +- {se:.{digits}f}", f"{judged(word)}, {distance(mean, se)} SE"


if len(sys.argv) != 2:
    sys.exit("usage: per_seed_rows.py FOLDER  (a folder evaluate.py wrote: "
             "results/powerlift-10M/robust-5M)")
table = Path(sys.argv[1]) / "per_seed.csv"
if not table.is_file():
    sys.exit(f"per_seed_rows.py: no {table}: give a folder evaluate.py wrote")
with table.open() as file:
    rows = list(csv.DictReader(file))
needed = {BASELINE, *ACTIONS}
policies: dict[tuple[int, int], dict[str, dict]] = {}
for row in rows:
    policies.setdefault((int(row["seed"]), int(row["step"])), {})[row["selector"]] = row
for (seed, step), by in sorted(policies.items()):
    if not needed <= set(by) or not by["mode"].get("fell_difference_se"):
        sys.exit(f"per_seed_rows.py: {table} needs the actions {sorted(needed)} and how episodes "
                 "ended (end_fell); re-run evaluate.py with them")
    base = by[BASELINE]
    cells = [f"{float(base['return_mean']):.1f} +- {float(base['return_se']):.1f}"]
    for action in ACTIONS:
        value, word = difference(float(by[action]["difference_mean"]),
                                 float(by[action]["difference_se"]), 1)
        cells.append(f"{value} ({word})")
    mode = by["mode"]
    value, word = difference(float(mode["fell_difference_mean"]),
                             float(mode["fell_difference_se"]), 2, fall_verdict)
    cells.append(f"{mode['end_fell']} / {base['end_fell']} ({value}: {word})")
    cells.append(f"{mode['end_time_limit']} / {base['end_time_limit']}")
    print(f"| {seed} | {step / 1e6:g}M | " + " | ".join(cells) + " |")
