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

HERE = Path(__file__).resolve().parent
CUBE_10M = HERE.parent / "cube-10M"
LAST = 4_000_000
COLORS = {2: "tab:blue", 3: "tab:orange"}


def rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as file:
        return list(csv.DictReader(file))


def seed_of(run: Path) -> int:
    return int(run.name.split("__seed")[1].split("__")[0])


def log_curve(run: Path) -> tuple[list[float], list[float]]:
    points = [(int(r["global_step"]), float(r["tanh_mu_return_mean"]))
              for r in rows(run / "eval.csv") if int(r["global_step"]) <= LAST]
    return [s / 1e6 for s, _ in points], [v for _, v in points]


def robust_points(campaign: Path) -> dict[int, list[tuple[float, float, float]]]:
    """seed -> (step in millions, tanh(mu) mean, SE) from every robust-*/per_seed.csv."""
    found: dict[int, list] = {}
    for table in sorted(campaign.glob("robust-*/per_seed.csv")):
        for r in rows(table):
            if r["selector"] == "tanh_mu" and int(r["step"]) <= LAST:
                found.setdefault(int(r["seed"]), []).append(
                    (int(r["step"]) / 1e6, float(r["return_mean"]), float(r["return_se"])))
    return found


def main(out: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 5))
    for campaign, style, name in ((HERE, "-", "HumanoidBench's scene, MuJoCo 3.1.6"),
                                  (CUBE_10M, "--", "cube-10M: our scene, MuJoCo 4.0.0")):
        for run in sorted((campaign / "runs").glob("*seed[23]__*")):
            seed = seed_of(run)
            ax.plot(*log_curve(run), style, color=COLORS[seed], lw=1.4,
                    label=f"ours, seed {seed}, {name}")
        for seed, points in robust_points(campaign).items():
            steps, means, ses = zip(*sorted(points), strict=True)
            ax.errorbar(steps, means, yerr=ses, fmt="o" if style == "-" else "s",
                        mfc=COLORS[seed] if style == "-" else "white", color=COLORS[seed],
                        ms=6, capsize=2, lw=0)
    hb = rows(HERE / "humanoidbench-sac-cube.csv")
    for k, seed in enumerate(("seed_0", "seed_1", "seed_2")):
        ax.plot([int(r["step"]) / 1e6 for r in hb], [float(r[seed]) for r in hb], "^:",
                color="0.35", ms=6, label="HumanoidBench's SAC, 3 seeds" if k == 0 else None)
    ax.axhline(27.3, color="0.6", lw=0.8)
    ax.text(0.05, 28.2, "HumanoidBench's lowest seed at 4M (27.3)", fontsize="small",
            color="0.4", va="bottom")
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
