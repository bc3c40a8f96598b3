"""Issue 88's first question: is our SAC the SAC people mean? Per task, our tanh(mu) return at
1M (the robust evaluation's mean over seeds, with its t-interval) beside each published SAC's
figure (published-sacs.csv, from published-sacs.md: library, version of the task, seeds, what
its number is), as a markdown table on stdout and a figure.

    .venv/bin/python results/classic-1M/beside_published.py [--runs DIR] [--robust DIR] [--out PNG]
    .venv/bin/python results/classic-1M/beside_published.py --training-only  # from train.csv

Ours also in CleanRL's own measure, beside CleanRL's figure: each seed's mean over its last 100
training episodes to 1M, then mean and population std over seeds (--training-only: that alone,
while the runs go on).

Defaults: this folder's runs/, robust-1M/ and beside-published.png. Ours run the v5 tasks; no
source publishes SAC on v5, and the sources' numbers are of different kinds (CleanRL's are
training returns, Tianshou's a best point over training), so "below" or "above" is read against
the range of all of them, never against one.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # run as a file from the checkout: analysis/ beside it
from analysis import data, estimators  # noqa: E402
from sac_utils.files import complete_lines  # noqa: E402

STEP = 1_000_000
# CleanRL's figure is each seed's mean over its last 100 training episodes (openrlbenchmark's
# metric_last_n_average_window), then mean and population std over seeds: ours the same way.
LAST_EPISODES = 100
TASKS = ("Hopper", "HalfCheetah", "Walker2d", "Ant", "Humanoid")
# What each source's number is, for the table's header (published-sacs.md has the detail).
PROTOCOLS = {
    "CleanRL": "v4, 3 seeds, training returns of the last 100 episodes, +- std over seeds",
    "RL Zoo": "v3, 1 run, deterministic, ~150 episodes, +- std over episodes",
    "Tianshou": "v3, 10 seeds, best 10-seed mean of deterministic evaluations up to 1M, "
                "alpha fixed at 0.2, +- std over seeds",
    "Spinning Up": "v3, 10 seeds, deterministic, alpha 0.2, batch 100, read off its plot, "
                   "+- std over seeds",
}
MARKERS = {"CleanRL": "v", "RL Zoo": "D", "Tianshou": "^", "Spinning Up": "P"}
KINDS = {"CleanRL": "training returns", "RL Zoo": "one run", "Tianshou": "best point to 1M",
         "Spinning Up": "read off its plot"}


class BesideError(Exception):
    """A folder this needs is missing or holds no 1M evaluation: the message says which."""


def published(path: Path = HERE / "published-sacs.csv") -> pd.DataFrame:
    """The published figures, one row per (task, source)."""
    return pd.read_csv(path)


def task_name(env_id: str) -> str:
    """Hopper-v5 -> Hopper: the published rows name the task, not its version."""
    return env_id.split("-v")[0]


def ours(robust: data.Robust, step: int = STEP) -> pd.DataFrame:
    """Per task: our seeds' tanh(mu) returns at `step` (each seed's mean over its episodes), their
    mean and Student's 95% interval over seeds."""
    out = []
    for env_id, steps in data.robust_paired_differences(robust).items():
        if step not in steps:
            continue
        at = steps[step]
        mean, low, high = estimators.t_interval(at.returns[data.BASELINE])
        out.append({"task": task_name(env_id), "env_id": env_id, "seeds": len(at.seeds),
                    "episodes": int(at.episodes.min()), "mean": mean, "low": low,
                    "high": high})
    if not out:
        raise BesideError(f"no tanh_mu rows at step {step:,} in the robust folder(s); evaluate "
                          f"the {step:,}-step snapshots with --selectors ... tanh_mu")
    return pd.DataFrame(out)


def updates(runs: Path, step: int = STEP) -> pd.DataFrame:
    """Per task: how many updates its runs' policies had at `step`, mean and range over seeds.
    A run makes one update per env step from --learning-starts on, except while it refills its
    buffer after a restart from a snapshot (config.json's `restarts`): each one costs its
    refill's updates, so a restarted run meets the published SACs with fewer."""
    out = []
    for config_path in sorted(runs.glob("*/config.json")):
        config = data.read_config(config_path)
        lost = sum(min(r["updates_from"], step) - r["step"]
                   for r in config.get("restarts", []) if r["step"] < step)
        out.append({"task": task_name(config["env_id"]), "seed": config["seed"],
                    "updates": step - config["learning_starts"] - lost,
                    "restarts": len(config.get("restarts", []))})
    return pd.DataFrame(out, columns=["task", "seed", "updates", "restarts"])


def training_returns(runs: Path, step: int = STEP, last: int = LAST_EPISODES) -> pd.DataFrame:
    """Per task, ours in CleanRL's own measure: each seed's mean return over its last `last`
    training episodes up to `step` (the sampled actions it trained with), then the mean and the
    population std over the seeds whose train.csv reaches `step`. A train.csv row gives the
    episodes that ended in it and their mean return; the earliest row used counts in part."""
    seeds = []
    for config_path in sorted(runs.glob("*/config.json")):
        config, path = data.read_config(config_path), config_path.parent / "train.csv"
        if not path.is_file():
            continue
        log = pd.read_csv(io.StringIO("".join(complete_lines(path))))
        lacking = {"global_step", "episodes", "episode_return_mean"} - set(log.columns)
        if lacking:
            raise BesideError(f"{path} lacks column(s) {sorted(lacking)}: not a train.csv the "
                              "scripts write; restore it")
        if log.empty or log.global_step.max() < step:
            continue
        log = log[(log.global_step <= step) & (log.episodes > 0)].iloc[::-1]
        counts, means = log.episodes.to_numpy(float), log.episode_return_mean.to_numpy(float)
        before = np.concatenate(([0.0], np.cumsum(counts)[:-1]))
        taken = np.clip(last - before, 0, counts)
        seeds.append({"task": task_name(config["env_id"]), "seed": config["seed"],
                      "return": float(taken @ means / taken.sum())})
    per_seed = pd.DataFrame(seeds, columns=["task", "seed", "return"])
    return per_seed.groupby("task")["return"].agg(
        mean="mean", std=lambda r: float(np.std(r)), seeds="size").reset_index()


def placement(mean: float, low: float, high: float, values: np.ndarray) -> str:
    """Where our interval falls against the published values at 1M."""
    if values.size == 0:
        return "no published value at 1M"
    lowest, highest = values.min(), values.max()
    span = f"{lowest:.0f}-{highest:.0f}"
    if high < lowest:
        return f"**below every one** ({span})"
    if low > highest:
        return f"**above every one** ({span})"
    if mean < lowest:
        return f"mean below every one ({span}); the interval reaches the lowest"
    if mean > highest:
        return f"mean above every one ({span}); the interval reaches the highest"
    return f"within ({span})"


def table(our: pd.DataFrame, peers: pd.DataFrame, done: pd.DataFrame | None = None,
          trained: pd.DataFrame | None = None) -> str:
    """The README's markdown table: a row per task, ours then each source, then the reading;
    with `done` (updates()), a column of our updates at 1M; with `trained`
    (training_returns()), ours in CleanRL's measure beside CleanRL's."""
    sources = list(PROTOCOLS)
    head = ["task", "ours (v5): tanh(mu) at 1M, mean [95% t-interval], seeds x starts",
            *(f"{s} ({PROTOCOLS[s]})" for s in sources), "ours against the published at 1M"]
    if trained is not None:
        head.insert(3, f"ours in CleanRL's measure (last {LAST_EPISODES} training episodes to "
                       "1M, +- std over seeds; seeds)")
    if done is not None:
        head.append("our updates at 1M, mean (min-max) over seeds; restarts (without one: 1M "
                    "less its --learning-starts)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for task in TASKS:
        mine = our[our.task == task]
        theirs = peers[peers.task == task]
        if mine.empty:
            cells = [task, "not evaluated"]
        else:
            m = mine.iloc[0]
            spread = (f"[{m.low:.0f}, {m.high:.0f}]" if m.seeds > 1
                      else "(one seed: no interval)")
            cells = [task, f"{m['mean']:.0f} {spread}, {m.seeds} x {m.episodes}"]
        for source in sources:
            row = theirs[theirs.source == source]
            if row.empty:
                cells.append("not published")
                continue
            r = row.iloc[0]
            at = "" if r.step == STEP else f" at {r.step // 1_000_000}M (none at 1M)"
            cells.append(f"{r.value} +- {r.spread}{at}")
        if trained is not None:
            cells.insert(3, trained_cell(trained, task))
        at_step = theirs[theirs.step == STEP].value.to_numpy(dtype=float)
        cells.append("" if mine.empty else placement(m["mean"], m.low, m.high, at_step))
        if done is not None:
            runs = done[done.task == task]
            cells.append("no runs" if runs.empty else
                         f"{runs.updates.mean():,.0f} ({runs.updates.min():,}-"
                         f"{runs.updates.max():,}); {runs.restarts.sum()}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def trained_cell(trained: pd.DataFrame, task: str) -> str:
    """A task's cell of ours in CleanRL's measure (training_returns())."""
    mine = trained[trained.task == task]
    if mine.empty:
        return "no run at 1M"
    m = mine.iloc[0]
    return f"{m['mean']:.0f} +- {m['std']:.0f}; {m.seeds}"


def training_table(trained: pd.DataFrame, peers: pd.DataFrame) -> str:
    """Ours in CleanRL's measure beside CleanRL's, a row per task with a run at 1M."""
    cleanrl = peers[(peers.source == "CleanRL") & (peers.step == STEP)]
    lines = [f"| task | ours (v5): last {LAST_EPISODES} training episodes to 1M, mean +- std over "
             f"seeds; seeds | CleanRL ({PROTOCOLS['CleanRL']}) |", "|---|---|---|"]
    for task in TASKS:
        if task not in set(trained.task):
            continue
        theirs = cleanrl[cleanrl.task == task]
        lines.append(f"| {task} | {trained_cell(trained, task)} | "
                     + (f"{theirs.iloc[0].value} +- {theirs.iloc[0].spread}" if not theirs.empty
                        else "not published") + " |")
    return "\n".join(lines)


def figure(runs: Path | None, our: pd.DataFrame, peers: pd.DataFrame, out: Path) -> None:
    """One panel per task: each seed's training-log tanh(mu) rounds, our 1M mean with its
    t-interval, and the published figures at 1M with their spreads."""
    curves: dict[str, list[data.Curve]] = {}
    if runs is not None:
        loaded, _ = data.load_runs([runs])
        for env_id, groups in loaded.items():
            curves[task_name(env_id)] = groups.get((data.CORRECTED, data.BASELINE), [])
    fig, axes = plt.subplots(1, len(TASKS), figsize=(3.3 * len(TASKS), 3.9))
    for ax, task in zip(axes, TASKS, strict=True):
        for curve in curves.get(task, []):
            ax.plot(curve.steps / 1e6, curve.returns, color="tab:blue", lw=0.7, alpha=0.45)
        mine = our[our.task == task]
        if not mine.empty:
            m = mine.iloc[0]
            ax.errorbar([1.0], [m["mean"]], yerr=[[m["mean"] - m.low], [m.high - m["mean"]]],
                        fmt="s", color="black", ms=6, capsize=3, zorder=5,
                        label=f"ours, 1M: mean of {m.seeds} seeds, 95% t-interval"
                        if m.seeds > 1 else "ours, 1M: one seed")
        for k, source in enumerate(PROTOCOLS):
            row = peers[(peers.task == task) & (peers.source == source) & (peers.step == STEP)]
            if row.empty:
                continue
            r = row.iloc[0]
            ax.errorbar([1.04 + 0.04 * k], [r.value], yerr=[r.spread], fmt=MARKERS[source],
                        color="0.35", ms=6, capsize=2, lw=0.8,
                        label=f"{source} ({KINDS[source]}), 1M +- std over {r.spread_of}")
        ax.set_title(task, fontsize="medium")
        ax.set_xlim(0, 1.22)
        ax.set_xlabel("Environment steps (millions)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("Return")
    handles = {label: h for ax in axes for h, label in zip(*ax.get_legend_handles_labels(),
                                                            strict=True)}
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=3, fontsize="small",
               frameon=False)
    seeds = int(our.seeds.max()) if not our.empty else 0
    fig.suptitle(f"Our SAC (sac_corrected.py's paired tanh(mu), v5 tasks, {seeds} seeds; "
                 "lines: each seed's training-log rounds) beside the published SACs at 1M "
                 "(v3/v4; protocols differ, see the README)", fontsize="medium")
    fig.tight_layout(rect=(0, 0.1, 1, 0.95))
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=Path, default=HERE / "runs")
    parser.add_argument("--robust", type=Path, default=HERE / "robust-1M")
    parser.add_argument("--out", type=Path, default=HERE / "beside-published.png")
    parser.add_argument("--training-only", action="store_true",
                        help="only ours in CleanRL's measure beside CleanRL's, from the runs' "
                             "train.csv (no robust evaluation needed: while the runs go on)")
    args = parser.parse_args(argv)
    try:
        if args.training_only:
            if not args.runs.is_dir():
                raise BesideError(f"{args.runs} is not a folder: pass --runs")
            print(training_table(training_returns(args.runs), published()))
            return 0
        for folder in (args.runs, args.robust):
            if not folder.is_dir():
                raise BesideError(f"{folder} is not a folder: pass --runs and --robust, or "
                                  "commit the campaign's runs/ and robust-1M/ first")
        our, peers = ours(data.load_robust([args.robust])), published()
        print(table(our, peers, updates(args.runs), training_returns(args.runs)))
        figure(args.runs, our, peers, args.out)
    except (BesideError, data.AnalysisError) as error:
        print(f"beside_published.py: {error}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
