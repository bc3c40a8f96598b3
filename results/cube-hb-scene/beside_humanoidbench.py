"""The issue's figure: these runs' tanh(mu) over training beside cube-10M's seeds 2 and 3 and
HumanoidBench's three SAC seeds, 0-4M steps.

    .venv/bin/python results/cube-hb-scene/beside_humanoidbench.py [OUT]  # default: beside it

Lines: each run's training-log round (eval.csv's tanh_mu_return_mean, 10 episodes every 100k);
dotted, where a run was restarted from a snapshot (`sweep.py restart`), its rounds past that step
as it first ran them (restarts/step<N>/eval.csv).
Markers with bars: the 300-start robust evaluations (mean +- 1 SE) where a robust-*/ folder has
the snapshot. HumanoidBench's: its published curves at each million (humanoidbench-sac-cube.csv,
read as cube-10M's README says), mean of its deterministic evaluation episodes.

It then prints the reading that issue 86 set before the runs, applied to the robust evaluations
(`reading`): "the env" where both runs score at or above HumanoidBench's lowest seed at 4M and
rose from 3M, "cleared" where both score at or below ours (<= ~23), "between" otherwise.
"""

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # run as a file from the checkout: analysis/ beside it
from analysis import data  # noqa: E402

CUBE_10M = HERE.parent / "cube-10M"
LAST = 4_000_000
BEFORE = LAST - 1_000_000  # "rising": above the run's own evaluation a million steps before
COLORS = {2: "tab:blue", 3: "tab:orange"}
# The "at or below ours (<= ~23)": cube-10M's better seed scored 22.3 at 4M.
OURS = 23.0


def log_curves(campaign: Path) -> list[data.Curve]:
    """Each run's tanh(mu) rounds, as analyze.py reads them (the corrected runs' paired curve)."""
    runs, _ = data.load_runs([campaign / "runs"])
    return [c for groups in runs.values() for c in groups[(data.CORRECTED, data.BASELINE)]]


def lost_rounds(campaign: Path) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Per restarted run, (seed, steps, tanh(mu) returns) of its first rounds past the restart's
    step, read as analyze.py reads eval.csv from the copy the restart kept in restarts/step<N>/,
    with the round at the step itself to join the line."""
    lost = []
    for kept in sorted(campaign.glob(f"runs/*/restarts/step*/{data.EVAL_FILE}")):
        step = int(kept.parent.name.removeprefix("step"))
        seed = data.read_config(kept.parents[2] / data.CONFIG_FILE)["seed"]
        columns, _ = data.read_eval_csv(kept)
        steps = columns[data.STEP_COLUMN]
        after = (steps >= step) & (steps <= LAST)
        lost.append((seed, steps[after],
                     columns[f"{data.BASELINE}_{data.RETURN_COLUMN}"][after]))
    return lost


def robust_rows(campaign: Path) -> pd.DataFrame:
    """Every robust-*/ folder's tanh(mu) rows up to LAST, as analyze.py's --robust reads them."""
    rows = data.load_robust(sorted(campaign.glob("robust-*/"))).rows
    return rows[(rows.selector == data.BASELINE) & (rows.step <= LAST)]


def reading(means: dict[int, dict[int, float]], bar: float) -> str:
    """Issue 86's rule on the robust tanh(mu) means, means[seed][step]: both runs at or above
    `bar` (HumanoidBench's lowest seed at 4M) and above their own 3M: the env; both at or below
    OURS: cleared; otherwise between. Not yet while a run has no 4M evaluation."""
    if not means or any(LAST not in steps for steps in means.values()):
        return "the reading (issue 86's rule): not yet, a run has no 4M evaluation"
    numbers = "; ".join(f"seed {seed}: {steps.get(BEFORE, float('nan')):.1f} at 3M, "
                        f"{steps[LAST]:.1f} at 4M" for seed, steps in sorted(means.items()))
    at_4m = [steps[LAST] for steps in means.values()]
    rising = all(steps[LAST] > steps.get(BEFORE, float("inf"))
                 for steps in means.values())
    if all(x >= bar for x in at_4m) and rising:
        verdict = (f"the env: both at or above HumanoidBench's lowest seed ({bar:g}) and rising, "
                   "so the cube results must say that their env learns differently")
    elif all(x <= OURS for x in at_4m):
        verdict = f"cleared: both at or below ours (<= {OURS:g}), the gap is the SAC or chance"
    else:
        verdict = (f"between: neither both at or above {bar:g} and rising, nor both at or below "
                   f"{OURS:g}")
    return f"the reading (issue 86's rule): {verdict} ({numbers})"


def main(out: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 5))
    robust = {HERE: robust_rows(HERE), CUBE_10M: robust_rows(CUBE_10M)}
    for campaign, style, name in ((HERE, "-", "HumanoidBench's scene, MuJoCo 3.1.6"),
                                  (CUBE_10M, "--", "cube-10M: our scene, MuJoCo 4.0.0")):
        for curve in log_curves(campaign):
            kept = curve.steps <= LAST
            ax.plot(curve.steps[kept] / 1e6, curve.returns[kept], style,
                    color=COLORS[curve.seed], lw=1.4, label=f"ours, seed {curve.seed}, {name}")
        for seed, steps, returns in lost_rounds(campaign):
            ax.plot(steps / 1e6, returns, ":", color=COLORS[seed], lw=1.2)
        for seed, points in robust[campaign].groupby("seed"):
            ax.errorbar(points.step / 1e6, points.return_mean, yerr=points.return_se,
                        fmt="o" if style == "-" else "s", color=COLORS[seed],
                        mfc=COLORS[seed] if style == "-" else "white", ms=6, capsize=2, lw=0)
    with (HERE / "humanoidbench-sac-cube.csv").open(newline="") as file:
        hb = list(csv.DictReader(file))
    for k, seed in enumerate(("seed_0", "seed_1", "seed_2")):
        ax.plot([int(r["step"]) / 1e6 for r in hb], [float(r[seed]) for r in hb], "^:",
                color="0.35", ms=6, label="HumanoidBench's SAC, 3 seeds" if k == 0 else None)
    last = next(r for r in hb if int(r["step"]) == LAST)
    lowest = min(float(last[f"seed_{k}"]) for k in range(3))  # the bar for "the env"
    ax.axhline(lowest, color="0.6", lw=0.8)
    ax.text(0.05, lowest + 0.9, f"HumanoidBench's lowest seed at 4M ({lowest:g})",
            fontsize="small", color="0.4", va="bottom")
    ax.set_xlim(0, LAST / 1e6 + 0.1)
    ax.set_xlabel("Environment steps (millions)")
    ax.set_ylabel("tanh(mu) return")
    ax.set_title("h1hand cube, tanh(mu), one line per seed: 2 of ours per scene, 3 of"
                 " HumanoidBench's\n"
                 "lines: training log (10 episodes / 100k); markers: 300 noisy starts, mean"
                 " +- 1 SE\n(filled: HB scene; open: cube-10M); triangles: HumanoidBench's"
                 " published curves at each million;\ndotted: rounds lost with a machine (restarts"
                 " from the 3M snapshots; a second at 3.85M lost none)", fontsize="medium")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(0, 0.93))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(out)
    means = {seed: dict(zip(points.step, points.return_mean, strict=True))
             for seed, points in robust[HERE].groupby("seed")}
    print(reading(means, lowest))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "beside-humanoidbench.png")
