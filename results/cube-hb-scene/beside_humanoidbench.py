"""The issue's figure: these runs' tanh(mu) over training beside cube-10M's seeds 2 and 3 and
HumanoidBench's three SAC seeds, 0-4M steps.

    .venv/bin/python results/cube-hb-scene/beside_humanoidbench.py [OUT]  # default: beside it

Lines: each run's training-log round (eval.csv's tanh_mu_return_mean, 10 episodes every 100k).
Markers with bars: the 300-start robust evaluations (mean +- 1 SE) where a robust-*/ folder has
the snapshot. HumanoidBench's: its published curves at each million (humanoidbench-sac-cube.csv,
read as cube-10M's README says), mean of its deterministic evaluation episodes.
"""

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # run as a file from the checkout: analysis/ beside it
from analysis import data  # noqa: E402

CUBE_10M = HERE.parent / "cube-10M"
LAST = 4_000_000
COLORS = {2: "tab:blue", 3: "tab:orange"}


def log_curves(campaign: Path) -> list[data.Curve]:
    """Each run's tanh(mu) rounds, as analyze.py reads them (the corrected runs' paired curve)."""
    runs, _ = data.load_runs([campaign / "runs"])
    return [c for groups in runs.values() for c in groups[(data.CORRECTED, data.BASELINE)]]


def robust_rows(campaign: Path) -> pd.DataFrame:
    """Every robust-*/ folder's tanh(mu) rows up to LAST, as analyze.py's --robust reads them."""
    rows = data.load_robust(sorted(campaign.glob("robust-*/"))).rows
    return rows[(rows.selector == data.BASELINE) & (rows.step <= LAST)]


def main(out: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 5))
    for campaign, style, name in ((HERE, "-", "HumanoidBench's scene, MuJoCo 3.1.6"),
                                  (CUBE_10M, "--", "cube-10M: our scene, MuJoCo 4.0.0")):
        for curve in log_curves(campaign):
            kept = curve.steps <= LAST
            ax.plot(curve.steps[kept] / 1e6, curve.returns[kept], style,
                    color=COLORS[curve.seed], lw=1.4, label=f"ours, seed {curve.seed}, {name}")
        for seed, points in robust_rows(campaign).groupby("seed"):
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
                 " published curves at each million", fontsize="medium")
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(0, 0.93))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "beside-humanoidbench.png")
