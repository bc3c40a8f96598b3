"""From a folder of SAC runs to the paper's statistics and figures (its Figures 5-8), with rliable.

    python analyze.py runs/ --out report/
    python analyze.py runs/ --out report/ --robust robust/   # with evaluate.py's campaign

The headline is paired: per seed, each evaluation action minus tanh(mu) of the same actor from
the same start states; then the paper's unpaired rliable statistics. Here: the command line and
one section per report, in summary.md's order; what they read, estimate, draw and write is
analysis/'s. docs/analyze.md maps each figure and table to its code.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import matplotlib
import numpy as np
import seaborn as sns
import tyro
from rliable import metrics

from analysis.data import (
    ACTIONS,
    BASELINE,
    CHOICE_SHARES,
    CORRECTED,
    DIMENSION_SHIFT_COLUMNS,
    LAST_ROUNDS,
    OVER_TRAINING_SHIFT_COLUMNS,
    PAIRED_RETURN_COLUMN,
    STANDARD,
    SUCCESS_BARS,
    Aggregate,
    AnalysisError,
    Key,
    Pairing,
    Robust,
    RobustStep,
    Runs,
    Task,
    align,
    blowups_recorded,
    build_aggregate,
    build_study,
    cpu_name,
    eval_suffix,
    group_name,
    group_rank,
    is_own,
    last_rounds_averages,
    load_robust,
    load_runs,
    logged_at,
    normalize,
    normalizers,
    one_episode_per_seed,
    ordered_groups,
    own_action,
    paired_difference_curves,
    paired_differences,
    paired_groups,
    resolve_normalization,
    restart_marks,
    robust_dimension_study,
    robust_paired_differences,
    robust_shared_steps,
    shift_curves,
    standard_from_paired,
)
from analysis.estimators import (
    AGGREGATE_METRICS,
    FEW_SEEDS,
    VERDICT_SE,
    aggregate_estimates,
    difference_over_tasks,
    excludes_zero,
    interval_estimates,
    iqm_per_step,
    mean_curves,
    performance_profiles,
    seed_mean_estimates,
    t_interval,
    verdict,
)
from analysis.figures import (
    PairedCell,
    PairedRow,
    marker_shapes,
    plot_aggregate_metrics,
    plot_dimension_study,
    plot_over_training,
    plot_paired,
    plot_per_seed,
    plot_performance_profiles,
    plot_probability_of_improvement,
    plot_reward_curves,
    plot_sample_efficiency,
    profile_thresholds,
)
from analysis.report import (
    Report,
    above_zero,
    counted,
    format_step,
    interval_text,
    markdown_table,
    per_seed_tables,
    seed_cells,
    share_above_zero,
)
from sac_utils.cli import broken_rule

# ============================================================================== what to edit
# A task's success bar and a new evaluation action: analysis/data.py (SUCCESS_BARS, ACTIONS).
# Each group's colour, an index in seaborn's colorblind palette, fixed so that colours stay put
# between reports (an algorithm's actions get distant hues); any other gets a free colour.
COLORS = {(STANDARD, "tanh_mu"): 0, (CORRECTED, "mode"): 1, (CORRECTED, "tanh_mu"): 9,
          (STANDARD, "mode"): 3, (CORRECTED, "mean"): 2, (STANDARD, "mean"): 5,
          (CORRECTED, "q_best"): 4, (STANDARD, "q_best"): 6}

# ----------------------------------------------------------------------------- groups and settings
COMPARISON = ((CORRECTED, "mode"), (STANDARD, BASELINE))  # probability of improvement: x > y
STANDARD_LABEL = "Standard SAC"
ALGORITHM_LABELS = {STANDARD: STANDARD_LABEL, CORRECTED: "Corrected SAC"}
STANDARD_FROM_PAIRED_LABEL = "Standard SAC (tanh(mu), paired)"
NORMALIZATIONS = {
    "auto": "success-bar when every task has a HumanoidBench success bar, otherwise min-max",
    "success-bar": "score = return / HumanoidBench success bar (1.0 = solved)",
    "min-max": "score = (return - task min) / (task max - task min), over every return logged "
    "for the task in this folder (all algorithms, seeds and steps)",
    "none": "raw returns",
}
SCORE_NAMES = {"success-bar": "Success-bar normalised score",
               "min-max": "Min-max normalised score", "none": "Return"}


@dataclasses.dataclass
class Args:
    runs_dirs: tyro.conf.Positional[tuple[Path, ...]]
    """folder(s) holding the run folders (config.json + eval.csv), searched at any depth; several
    folders make one report (e.g. one campaign folder per task)"""
    out: Path = Path("report")
    """folder the figures, summary.md and summary.csv are written to"""
    normalize: Literal["auto", "success-bar", "min-max", "none"] = "auto"
    """per-task scores: return / HumanoidBench success bar, task range to [0, 1], or raw; auto:
    success-bar when every task has a bar, otherwise min-max"""
    at_step: int | None = None
    """score every run at this step instead of the last step all runs of its task share"""
    reps: int = 50_000
    """bootstrap replications for point estimates (aggregates, per-task finals, paired)"""
    curve_reps: int = 2_000
    """bootstrap replications for curves, profiles and probability of improvement"""
    curve_points: int = 51
    """steps on the sample-efficiency curve (evenly spaced over the shared steps, last included)"""
    seed: int = 0
    """seeds NumPy's global generator before every bootstrap (rliable ignores random_state)"""
    format: tuple[Literal["png", "pdf"], ...] = ("png",)
    """figure formats, e.g. `--format pdf` or `--format png pdf`"""
    robust: tuple[Path, ...] = ()
    """folders evaluate.py wrote over a campaign (evaluation.json + one episodes.csv per run; one
    per task, or several tasks in one): adds the robust evaluation's section and figure"""


# ============================================================================== shared tools
# ------------------------------------------------------------------------- few seeds
def few_seeds_lines(seeds: Sequence[int]) -> list[str]:
    """summary.md's warning where a mean over seeds has a bootstrap CI from FEW_SEEDS or fewer."""
    return ["", f"With {FEW_SEEDS} seeds or fewer a percentile bootstrap CI is narrower than "
            "the data allow: read the t-interval."] if seeds and min(seeds) <= FEW_SEEDS else []


def iqm_note(runs: Sequence[int], tasks: int) -> str:
    """With few runs per task, which runs IQM (a 25% trimmed mean over runs x tasks) keeps, and
    with one task that the median (over tasks of each task's mean) is the mean."""
    if not runs or max(runs) > FEW_SEEDS:
        return ""
    kept = " or ".join(f"the middle {n * tasks - 2 * int(0.25 * n * tasks)} of {n * tasks}"
                       for n in runs)
    return (f"{' or '.join(map(str, runs))} runs x {counted(tasks, 'task')}: IQM is the mean of "
            f"{kept} runs" + ("; the median is the mean" if tasks == 1 else ""))


# ------------------------------------------- paired differences: the headline's and the robust's
def difference_rows(report: Report, section: str, task: str, key: Key | str, step: int,
                    diffs: np.ndarray, boot: Sequence[float], scale: float | None = None,
                    suffix: str = "") -> None:
    """summary.csv's rows of one paired difference, one value per seed: the mean with its
    bootstrap CI (`boot`) and t-interval, in returns and (given `scale`) scores; the share of
    seeds above zero."""
    n, t_values = diffs.size, t_interval(diffs)
    for unit, divisor in (("return", 1.0), ("score", scale)):
        if divisor is not None:
            report.row(section, task, key, f"{unit}{suffix}", step, n,
                       *(v / divisor for v in boot))
            report.row(section, task, key, f"{unit}{suffix}_t", step, n,
                       *(v / divisor for v in t_values))
    report.row(section, task, key, f"share_above_zero{suffix}", step, n, share_above_zero(diffs),
               math.nan, math.nan)


OVER_TASKS_HEADER = ["tasks", "seeds per task", "difference (bootstrap CI)",
                     "t-interval (Welch)", "above zero (task, seed)"]


def over_tasks(report: Report, section: str, key: Key | str, per_task: dict[str, np.ndarray],
               step: int | str, shapes: dict[str, str], args: Args) -> tuple[PairedCell, list]:
    """A paired difference over tasks (difference_over_tasks of per-seed scores): summary.csv's
    rows, the figure's cell and summary.md's row under OVER_TASKS_HEADER."""
    scores, boot, t_values = difference_over_tasks(list(per_task.values()), args.reps,
                                                   args.seed)
    seeds = scores.shape[0]
    report.row(section, "all", key, "mean_score", step, seeds, *boot)
    report.row(section, "all", key, "mean_score_t", step, seeds, *t_values)
    report.row(section, "all", key, "share_above_zero", step, scores.size,
               share_above_zero(scores), math.nan, math.nan)
    markers = [shapes[t] for t in per_task for _ in range(seeds)]  # each task's seeds in turn
    return (PairedCell(scores.T.ravel(), boot, t_values, markers=markers),
            [len(per_task), seeds, interval_text(*boot, runs=seeds),
             f"[{t_values[1]:.3f}, {t_values[2]:.3f}]", above_zero(scores)])


def verdict_counts(means: np.ndarray, errors: np.ndarray) -> str:
    """summary.md's "ahead / level / behind": how many seeds each verdict() gives."""
    said = [verdict(m, se) for m, se in zip(means, errors, strict=True)]
    return " / ".join(str(said.count(v)) for v in ("ahead", "level", "behind"))


def episodes_span(episodes: np.ndarray) -> str:
    """Episodes per seed as the labels write them: "300", or "100-300" where seeds differ."""
    low, high = int(episodes.min()), int(episodes.max())
    return f"{low}" if low == high else f"{low}-{high}"


# ------------------------------------------------------------------------- labels and colours
@dataclasses.dataclass(frozen=True)
class GroupLabels:
    """A group's name in figures and tables, "Corrected SAC (mean eval)"; `standard`: from
    standard_label."""

    standard: str = STANDARD_LABEL

    def __call__(self, key: Key) -> str:
        return self.algorithm(key[0]) + eval_suffix(key)

    def algorithm(self, algorithm: str) -> str:
        return self.standard if algorithm == STANDARD else \
            ALGORITHM_LABELS.get(algorithm, algorithm)

    def action_first(self, key: Key) -> str:
        """"mean (Corrected SAC)": where the figure's series are actions."""
        return f"{ACTIONS.get(key[1], key[1])} ({self.algorithm(key[0])})"


def standard_label(pairing: Pairing, tasks: Sequence[str]) -> str:
    """What the standard group is: sac_standard.py runs, the paired evaluation, or a mix."""
    if not pairing.derived:
        return STANDARD_LABEL
    if len(pairing.derived) == len(tasks):
        return STANDARD_FROM_PAIRED_LABEL
    return STANDARD_FROM_PAIRED_LABEL.replace("paired", "paired on some tasks")


def group_colors(groups: list[Key]) -> dict[Key, tuple]:
    """Each group's colour: its fixed one, else a free one of the palette, else a dark one."""
    palette = sns.color_palette("colorblind", n_colors=10)
    extra = iter(c for i, c in enumerate(palette) if i not in COLORS.values())
    cycle = iter(sns.color_palette("dark", n_colors=max(len(groups), 1)))
    return {g: palette[COLORS[g]] if g in COLORS else next(extra, None) or next(cycle)
            for g in groups}


@dataclasses.dataclass(frozen=True)
class Analysis:
    """The data and the flags: what every report section reads (none changes it)."""

    args: Args  # --normalize resolved from auto
    runs: Runs
    tasks: dict[str, Task]
    groups: list[Key]  # every group, in group_order
    pairing: Pairing
    norms: dict[str, tuple[float, float]]  # task -> (offset, scale)
    aggregate: Aggregate | None  # the normalised scores of the groups compared across tasks
    labels: GroupLabels
    colors: dict[str, tuple]
    robust: Robust | None = None  # the --robust folders' per-seed rows, if given


def aggregate_title(agg: Aggregate) -> str:
    """Figures 7 and 8 name what they aggregate: the tasks and the runs per task."""
    runs = sorted({scores.shape[0] for scores in agg.final.values()})
    return f"{', '.join(agg.tasks)}: {' or '.join(map(str, runs))} runs per task and group"


def robust_labels_colors(actions: Sequence[str]) -> tuple[dict[str, str], dict[str, tuple]]:
    """Each evaluate.py action's name and colour: those of the group it stands for, tanh(mu)
    Standard SAC's, every other Corrected SAC's actors'."""
    keys = {a: (STANDARD if a == own_action(STANDARD) else CORRECTED, a) for a in actions}
    colors = group_colors(list(keys.values()))
    return ({a: GroupLabels().action_first(k) for a, k in keys.items()},
            {a: colors[k] for a, k in keys.items()})


# ============================================================================== the reports
# One section per report, in summary.md's order; each reads `analysis` and the shared tools,
# never another section.

# --------------------------------------- 1. the header, and where the standard numbers come from
def found_text(runs_dirs: Sequence[Path], runs: Runs, groups: list[Key]) -> str:
    """What the folder holds: how many runs, and per task and group how many seeds and the last
    step they reached."""
    rows = []
    for task, by_group in sorted(runs.items()):
        cells = []
        for group in groups:
            last = [curve.steps[-1] for curve in by_group.get(group, [])]
            if not last:
                cells.append("-")
                continue
            span = format_step(min(last)) + (f"-{format_step(max(last))}"
                                             if max(last) > min(last) else "")
            cells.append(f"{counted(len(last), 'seed')}, to step {span}")
        rows.append([task, *cells])
    # Run folders, not groups: a corrected folder also stands for the derived standard group.
    n_runs = len({curve.run_dir for by_group in runs.values() for curves in by_group.values()
                  for curve in curves})
    return (f"Found {n_runs} runs under {', '.join(map(str, runs_dirs))}:\n\n"
            + markdown_table(["task", *map(group_name, groups)], rows))


def normalization_line(mode: str, norms: dict[str, tuple[float, float]]) -> str:
    """The normalisation's numbers: each task's success bar or return range."""
    if mode == "success-bar":
        per_task = [f"{task} {scale:g}" for task, (_, scale) in norms.items()]
        return f"Success bars: {', '.join(per_task)}."
    if mode == "min-max":
        per_task = [f"{task} [{low:g}, {low + scale:g}]" for task, (low, scale) in norms.items()]
        return f"Return ranges mapped to [0, 1]: {', '.join(per_task)}."
    return ""


def pairing_lines(pairing: Pairing) -> list[str]:
    """summary.md's account of where the standard numbers come from."""
    lines = []
    if pairing.derived:
        lines.append(
            f"No sac_standard.py runs for {', '.join(pairing.derived)}: Standard SAC there is the "
            "corrected runs' paired evaluation, tanh(mu) of the same actors from the same start "
            "states (the two scripts make identical training decisions for a seed, so this is "
            "the standard run of each seed, computed once).")
    for task, points in sorted(pairing.agreeing.items()):
        lines.append(f"{task}: the standard runs equal the corrected runs' paired tanh(mu) "
                     f"evaluation at all {points} shared (seed, step) points.")
    lines += [f"Disagreement: {line}." for line in pairing.disagreeing]
    return lines


def summary_header(analysis: Analysis, chosen: str, found: str) -> list[str]:
    """summary.md's first lines: the normalisation (`chosen`: why), the intervals, the runs."""
    args = analysis.args
    return [
        f"# Analysis of {', '.join(map(str, args.runs_dirs))}", "",
        f"Normalisation {chosen}`{args.normalize}`: {NORMALIZATIONS[args.normalize]}. "
        + normalization_line(args.normalize, analysis.norms),
        f"Intervals: 95% stratified bootstrap (rliable), {args.reps:,} replications for point "
        f"estimates, {args.curve_reps:,} for curves, profiles and probability of improvement; "
        f"NumPy seed {args.seed}. Paired differences also get a Student-t 95% interval over "
        "seeds (t-interval), labelled as such.", "", found, "",
    ]


def report_standard_provenance(report: Report, analysis: Analysis) -> None:
    """summary.md's "Where the standard numbers come from" (pairing_lines). No estimator."""
    if pairing_lines(analysis.pairing):
        report.section("Where the standard numbers come from", *pairing_lines(analysis.pairing))


# ------------------------------------------------------- 2. the paired difference (headline)
def paired_over_tasks(report: Report, analysis: Analysis, differences: dict
                      ) -> tuple[list[str], PairedRow | None]:
    """Over tasks, each evaluation action's normalised paired difference (over_tasks):
    summary.md's lines and the figure's panel."""
    args, norms = analysis.args, analysis.norms
    name = SCORE_NAMES[args.normalize].lower()
    shapes = marker_shapes(list(differences))
    cells, table = {}, []
    for key in sorted({g for by_group in differences.values() for g in by_group}, key=group_rank):
        per_task = {t: d[key] / norms[t][1] for t, d in differences.items() if key in d}
        if len(per_task) >= 2:
            cells[0, key], row = over_tasks(report, "paired_difference", key, per_task, "",
                                            shapes, args)
            table.append([analysis.labels.action_first(key), *row])
    if not cells:
        return [], None
    lines = ["", f"Over tasks, each action minus tanh(mu) in {name}s: the mean over "
             "tasks with rliable's stratified bootstrap CI (seeds resampled within each task) "
             "and Welch's t-interval (the tasks' seeds independent); 'above zero': the (task, "
             "seed) pairs whose difference is positive.", "",
             markdown_table(["action", *OVER_TASKS_HEADER], table)]
    return lines, PairedRow(f"Over {len(shapes)} tasks at their scored steps", ["all tasks"],
                            cells, f"difference in {name}", shapes=shapes)


def paired_last_rounds(report: Report, analysis: Analysis, scored: dict, lines: list[str]
                       ) -> dict[tuple[str, Key], tuple[PairedCell, str]]:
    """Each seed's paired difference averaged over its last LAST_ROUNDS evaluation rounds: one
    round of a noisy task is one draw of its noise. `scored`: the scored step's estimates.
    Appends summary.md's table to `lines`; returns the figure's cells of the last LAST_ROUNDS[0]
    rounds, with their steps. Estimator: as at the scored step, on the averages."""
    args, runs, tasks, labels = analysis.args, analysis.runs, analysis.tasks, analysis.labels
    curves = paired_difference_curves(tasks, analysis.pairing.derived)
    averages, windows, notes = last_rounds_averages(tasks, curves)
    report.notes.extend(notes)
    if not averages:
        return {}
    estimates = seed_mean_estimates({(f"{t}|{k}", g): v for (t, g, k), v in averages.items()},
                                    args.reps, args.seed)
    table = []
    for task, by_group in curves.items():
        step = tasks[task].scored_step
        for group, diffs in by_group.items():
            last = diffs[:, np.searchsorted(tasks[task].steps, step)]
            cells = seed_cells(last, scored[task, group], 1)
            table.append([task, labels.algorithm(group[0]), group[1], last.size,
                          f"last ({format_step(step)})", *cells, above_zero(last)])
            for k in LAST_ROUNDS:
                if (task, group, k) not in averages:
                    continue
                values, window = averages[task, group, k], windows[task, k]
                estimate = estimates[f"{task}|{k}", group]
                difference_rows(report, "paired_last_rounds", task, group, step, values,
                                estimate, suffix=f"_last{k}")
                episodes = one_episode_per_seed(
                    [c for cs in runs[task].values() for c in cs], window)
                rounds = f"last {k} ({format_step(window[0])}-{format_step(window[-1])})" + \
                    (", one episode each" if episodes else "")
                table.append([task, labels.algorithm(group[0]), group[1],
                              values.size, rounds, *seed_cells(values, estimate, 1),
                              above_zero(values)])
    lines += ["", "Per seed, the difference averaged over the last "
              + " and the last ".join(map(str, LAST_ROUNDS)) + " shared rounds up to the scored "
              "step (one round is one draw of the evaluation noise), then over seeds as above; "
              "beside it the scored step's own.", "",
              markdown_table(["task", "algorithm", "action", "seeds", "rounds",
                              "return difference (bootstrap CI)", "t-interval", "above zero"],
                             table)]
    k = LAST_ROUNDS[0]
    return {(t, g): (PairedCell(v, estimates[f"{t}|{k}", g], t_interval(v)),
                     f"{format_step(windows[t, k][0])}-{format_step(windows[t, k][-1])}")
            for (t, g, kk), v in averages.items() if kk == k}


def report_paired_difference(report: Report, analysis: Analysis) -> None:
    """The headline (figure `paired_difference`): each evaluation action minus tanh(mu) of the
    same actors from the same start states, per task and over tasks, at the scored step and over
    the last rounds. Estimator, per task: the mean over seeds with the bootstrap CI
    (seed_mean_estimates), the pairing making each seed one value, and Student's t-interval,
    since with few seeds a percentile bootstrap is too narrow. Over tasks: paired_over_tasks."""
    args, runs, tasks, norms = analysis.args, analysis.runs, analysis.tasks, analysis.norms
    labels = analysis.labels
    differences = paired_differences(tasks, analysis.pairing.derived)
    if not differences:
        report.notes.append(f"no run carries the paired evaluation ({PAIRED_RETURN_COLUMN}): "
                            "paired differences skipped")
        return
    print(f"paired differences ({args.reps:,} reps) ...")
    estimates = seed_mean_estimates({(t, g): d for t, by_group in differences.items()
                                     for g, d in by_group.items()}, args.reps, args.seed)
    table, one_episode = [], []
    for task, by_group in differences.items():
        step, scale = tasks[task].scored_step, norms[task][1]
        if one_episode_per_seed([c for cs in runs[task].values() for c in cs], np.array([step])):
            one_episode.append(task)
        for group, diffs in by_group.items():
            values, n = estimates[task, group], diffs.size
            difference_rows(report, "paired_difference", task, group, step, diffs, values, scale)
            scaled = [v / scale for v in values]
            table.append([task, format_step(step), labels.algorithm(group[0]),
                          group[1], n, *seed_cells(diffs, values, 1),
                          seed_cells(diffs / scale, scaled)[0], above_zero(diffs)])
    seeds = [d.size for by_group in differences.values() for d in by_group.values()]
    lines = ["Per seed, at each task's scored step: an action's return minus tanh(mu)'s, same "
             "actor, same start states (q_best: the critic's pick of mode / tanh(mu) / mean). "
             "Mean over seeds with rliable's 95% bootstrap CI and the 95% t-interval (two "
             "seeds: the two values in place of the bootstrap CI); 'above zero': seeds whose "
             "difference is positive, a count of signs that decides nothing."]
    lines += few_seeds_lines(seeds)
    for task in one_episode:
        lines += ["", f"{task}: each seed's evaluation at "
                  f"{format_step(tasks[task].scored_step)} is one episode (`distinct_episodes` "
                  "= 1: no reset noise), one draw of that episode's noise."]
    lines += ["", markdown_table(["task", "step", "algorithm", "action", "seeds",
                                  "return difference (bootstrap CI)", "t-interval",
                                  "score difference (bootstrap CI)", "above zero"], table)]
    over_lines, over = paired_over_tasks(report, analysis, differences)
    lines += over_lines
    last_rounds = paired_last_rounds(report, analysis, estimates, lines)
    rows = []
    for task, by_group in differences.items():
        data, step = tasks[task], tasks[task].scored_step
        seeds = " or ".join(sorted({str(d.size) for d in by_group.values()}))
        ticks = [f"at {format_step(step)}\n{counted(seeds, 'seed')}"
                 + (", one episode each" if task in one_episode else "")]
        cells = {(0, g): PairedCell(d, estimates[task, g], t_interval(d))
                 for g, d in by_group.items()}
        spans = {last_rounds[task, g][1] for g in by_group if (task, g) in last_rounds}
        if spans:
            ticks.append(f"mean of the last {LAST_ROUNDS[0]} rounds\n{spans.pop()}")
            cells |= {(1, g): last_rounds[task, g][0] for g in by_group
                      if (task, g) in last_rounds}
        baseline = paired_groups(data, task in analysis.pairing.derived)[0][1]
        reference = (float(data.scored(baseline).mean()), f"at {format_step(step)}")
        rows.append(PairedRow(task, ticks, cells, "return minus tanh(mu)'s", reference))
    names = {g: labels.action_first(g) for by_group in differences.values() for g in by_group}
    report.figure(plot_paired(rows + ([over] if over else []), analysis.colors, names,
                              "the training log's evaluation rounds"), "paired_difference")
    report.section("Headline: paired difference, each evaluation action minus tanh(mu) of the "
                   "same actors", *lines)


# --------------------------------------------------- 3. the robust evaluation (evaluate.py)
def robust_per_task(report: Report, analysis: Analysis, by_task: dict[str, dict[int, RobustStep]]
                    ) -> tuple[list[list], dict]:
    """Per task, step and action: the mean return and paired difference over seeds. Writes
    summary.csv's rows; returns summary.md's table rows and the differences' bootstrap
    estimates, keyed ("task|step", action)."""
    args = analysis.args
    differences = {(f"{t}|{s}", a): d for t, steps in by_task.items()
                   for s, at in steps.items() for a, d in at.differences.items()}
    returns = {(f"{t}|{s}", a): r for t, steps in by_task.items()
               for s, at in steps.items() for a, r in at.returns.items()}
    estimates = seed_mean_estimates(differences, args.reps, args.seed)
    return_estimates = seed_mean_estimates(returns, args.reps, args.seed)
    recorded = blowups_recorded(by_task)
    table = []
    for task, steps in by_task.items():
        for step, at in steps.items():
            key, episodes = f"{task}|{step}", episodes_span(at.episodes)
            for action, action_returns in at.returns.items():
                n = action_returns.size
                mean_return = return_estimates[key, action]
                report.row("robust_return", task, action, "return", step, n, *mean_return)
                ends = at.unstable.get(action)
                if ends is not None:
                    report.row("robust_unstable_ends", task, action, "episodes", step, n, ends,
                               math.nan, math.nan)
                blowups = [] if not recorded else \
                    ["n/r" if ends is None else f"{ends} of {at.played[action]}"]
                cells = [task, format_step(step), action, n, episodes, f"{mean_return[0]:.1f}"]
                if action not in at.differences:
                    table.append([*cells, "(the baseline)", "", "", "", *blowups])
                    continue
                diffs, boot = at.differences[action], estimates[key, action]
                difference_rows(report, "robust_difference", task, action, step, diffs, boot,
                                SUCCESS_BARS.get(task))
                table.append([*cells, *seed_cells(diffs, boot, 1), above_zero(diffs),
                              verdict_counts(diffs, at.errors[action]), *blowups])
    return table, estimates


def robust_over_tasks(report: Report, analysis: Analysis,
                      barred: dict[str, dict[int, RobustStep]], step: int
                      ) -> tuple[PairedRow, dict[str, np.ndarray], list[str]]:
    """At the tasks' shared last step, each action's paired difference divided by each task's
    success bar (over_tasks, as the headline's). Writes summary.csv's rows; returns the
    figure's panel, each action's (seeds, tasks) normalised returns and summary.md's lines."""
    by_task, tasks = barred, list(barred)
    actions = [a for a in by_task[tasks[0]][step].returns
               if all(a in by_task[t][step].returns for t in tasks)]
    seeds = min(by_task[t][step].returns[a].size for t in tasks for a in actions)
    lines = [f"Over {counted(len(tasks), 'task')} at {format_step(step)}, each divided by its "
             f"success bar ({', '.join(f'{t} {SUCCESS_BARS[t]:g}' for t in tasks)}), {seeds} "
             "seeds per task: the difference's mean over tasks with rliable's stratified "
             "bootstrap CI and Welch's t-interval; the returns' aggregate metrics.", ""]
    scores = {a: np.stack([by_task[t][step].returns[a][:seeds] / SUCCESS_BARS[t]
                           for t in tasks], axis=1) for a in actions}
    cells, table, shapes = {}, [], marker_shapes(tasks)
    for action in actions:
        if action in by_task[tasks[0]][step].differences:
            per_task = {t: by_task[t][step].differences[action][:seeds] / SUCCESS_BARS[t]
                        for t in tasks}
            cells[0, action], row = over_tasks(report, "robust_difference", action, per_task,
                                               step, shapes, analysis.args)
            table.append([action, *row])
    panel = PairedRow(f"Over {counted(len(tasks), 'task')} at {format_step(step)}, each divided "
                      "by its success bar", [f"{seeds} seeds per task"], cells,
                      "difference / success bar", shapes=shapes)
    return panel, scores, [*lines, markdown_table(["action", *OVER_TASKS_HEADER], table), ""]


def robust_ticks(steps: dict[int, RobustStep]) -> list[str]:
    """A task's ticks, one per step, in short lines (ten side by side must not run into each
    other); the CPU too where its steps ran on more than one kind (other draws of the episodes)."""
    machines = {at.machine for at in steps.values()}
    return [f"{format_step(s)}\n{episodes_span(at.episodes)} starts\nx {at.episodes.size} seeds"
            + (f"\n{at.machine or 'CPU n/r'}" if len(machines) > 1 else "")
            for s, at in steps.items()]


def robust_settings_lines(robust: Robust) -> list[str]:
    """summary.md's account of each --robust folder: where, episodes, reset noise, actions."""
    lines = []
    for folder, settings in robust.settings.items():
        noise, cpu = settings.get("reset_noise"), cpu_name(settings)
        lines.append(f"- `{folder}`: {len(settings['runs'])} runs, "
                     f"{settings.get('episodes', '?')} episodes per policy, reset noise "
                     f"{'the task' + chr(39) + 's own' if noise is None else f'+-{noise}'}, "
                     f"actions {', '.join(settings.get('selectors', []))}"
                     + (f", on {cpu} ({settings['machine'].get('cores', '?')} cores)" if cpu
                        else ""))
    return lines


def report_robust_evaluation(report: Report, analysis: Analysis) -> None:
    """Figures `robust_evaluation` and `robust_per_seed` (only with --robust): the headline's
    paired difference from evaluate.py's many noisy starts per seed and step. Estimator, per
    task and step: the mean over seeds of each seed's mean difference, with Student's
    t-interval and, labelled as such, the bootstrap (seed_mean_estimates), too narrow with few
    seeds. Over tasks: robust_over_tasks."""
    robust, args = analysis.robust, analysis.args
    if robust is None:
        return
    by_task = robust_paired_differences(robust)
    print(f"robust evaluation ({args.reps:,} reps) ...")
    table, estimates = robust_per_task(report, analysis, by_task)
    lines = ["From evaluate.py's campaign folders:", *robust_settings_lines(robust), "",
             "Each policy (final weights or a snapshot) played every action from the same noisy "
             "starts, episode by episode. Per seed, the mean over its episodes of the action's "
             "return minus tanh(mu)'s; over seeds, the mean with its 95% t-interval and rliable's "
             f"bootstrap ({args.reps:,} replications). 'return': the mean over seeds of each "
             "seed's mean return; 'above zero': seeds whose difference is positive (a count of "
             "signs that decides nothing); 'ahead / level / "
             f"behind': seeds more than {VERDICT_SE:g} standard errors of their paired "
             "episodes above zero, within, or below."]
    seeds = [d.size for steps in by_task.values() for at in steps.values()
             for d in at.differences.values()]
    lines += few_seeds_lines(seeds)
    recorded = blowups_recorded(by_task)
    if recorded:
        lines += ["", "'blow-ups': episodes over the seeds that a physics blow-up ended (the "
                  "return is what was earned until then); n/r: not recorded."]
    lines += ["", markdown_table(["task", "step", "action", "seeds", "episodes per seed",
                                  "return", "minus tanh(mu) (bootstrap CI)", "t-interval",
                                  "above zero", "ahead / level / behind",
                                  *(["blow-ups"] if recorded else [])], table)]
    lines += ["", "Per seed (evaluate.py's summary.md has the same tables):", "",
              *per_seed_tables(robust.rows.to_dict("records"), robust.actions)]
    over = None
    unbarred = [t for t in by_task if t not in SUCCESS_BARS]
    if unbarred:
        lines += ["", f"No success bar for {', '.join(unbarred)}: left out of the normalised "
                  "results over tasks."]
    barred = {t: steps for t, steps in by_task.items() if t in SUCCESS_BARS}
    step = max(robust_shared_steps(barred), default=None)
    if barred and step is None:
        lines += ["", "The tasks' robust evaluations share no step: no result over tasks."]
    elif step is not None:
        over, scores, over_lines = robust_over_tasks(report, analysis, barred, step)
        lines += ["", *over_lines]
    labels, colors = robust_labels_colors(robust.actions)
    rows = []
    for task, steps in by_task.items():
        ticks = robust_ticks(steps)
        cells = {(i, a): PairedCell(d, estimates[f"{task}|{step}", a], t_interval(d),
                                    at.errors.get(a), seeds=at.seeds)
                 for i, (step, at) in enumerate(steps.items()) for a, d in at.differences.items()}
        last = max(steps)
        reference = (float(steps[last].returns[BASELINE].mean()), f"at {format_step(last)}")
        rows.append(PairedRow(task, ticks, cells, "return minus tanh(mu)'s", reference))
    how = "the robust evaluation: evaluate.py's noisy starts"
    report.figure(plot_paired(rows + ([over] if over else []), colors, labels, how),
                  "robust_evaluation")
    report.figure(plot_per_seed(rows, colors, labels, how), "robust_per_seed")
    if over is not None:
        lines += report_robust_aggregate(report, analysis, scores, step, list(barred), labels,
                                         colors)
    lines += robust_sample_efficiency(report, analysis, barred, labels, colors)
    report.section("The robust evaluation: each action minus tanh(mu) from many noisy starts "
                   "(evaluate.py)", *lines)


def report_robust_aggregate(report: Report, analysis: Analysis, scores: dict[str, np.ndarray],
                            step: int, tasks: list[str], labels: dict, colors: dict) -> list[str]:
    """Figures `robust_aggregate_metrics` and `robust_performance_profiles`: Figures 6 and 7
    (as sections 7 and 8) of each action's normalised (seeds, tasks) returns. Writes
    summary.csv's `robust_aggregate` rows; returns summary.md's lines."""
    args, name = analysis.args, SCORE_NAMES["success-bar"]
    seeds = next(iter(scores.values())).shape[0]
    point, interval = aggregate_estimates(scores, True, args.reps, args.seed)
    report.figure(plot_aggregate_metrics(
        point, interval, scores, AGGREGATE_METRICS, colors, name, labels.get,
        f"The robust evaluation at {format_step(step)}, over {counted(len(tasks), 'task')}"),
        "robust_aggregate_metrics")
    print(f"robust performance profiles ({args.curve_reps:,} reps) ...")
    taus = profile_thresholds(scores)
    profiles = performance_profiles(scores, taus, args.curve_reps, args.seed)
    report.figure(plot_performance_profiles(
        taus, *profiles, scores, colors, name, labels.get, f"Robust evaluation at "
        f"{format_step(step)}: {', '.join(tasks)}, {seeds} seeds per task"),
        "robust_performance_profiles")
    rows = []
    for action in point:
        for i, metric in enumerate(AGGREGATE_METRICS):
            report.row("robust_aggregate", "all", action, metric, step, seeds,
                       point[action][i], *interval[action][:, i])
        rows.append([action, *(interval_text(point[action][i], *interval[action][:, i],
                                             runs=seeds)
                               for i in range(len(AGGREGATE_METRICS)))])
    lines = [markdown_table(["action", *AGGREGATE_METRICS], rows)]
    if note := iqm_note([seeds], len(tasks)):
        lines += ["", f"{note}."]
    return lines


def robust_sample_efficiency(report: Report, analysis: Analysis,
                             barred: dict[str, dict[int, RobustStep]], labels: dict,
                             colors: dict) -> list[str]:
    """Figure `robust_sample_efficiency`: Figure 8 (as section 9) of each action's returns
    divided by each success bar, over the tasks evaluated at two steps or more, at the steps
    they share. Writes summary.csv's rows; returns summary.md's lines."""
    args = analysis.args
    curves = {t: steps for t, steps in barred.items() if len(steps) >= 2}
    shared = robust_shared_steps(curves)
    if len(shared) < 2:
        return [] if not curves else [
            "", f"No robust sample-efficiency curve: {', '.join(curves)}, evaluated at several "
            "steps, share fewer than two of them."]
    tasks, at = list(curves), [[curves[t][step] for step in shared] for t in curves]
    actions = [a for a in at[0][0].returns if all(a in s.returns for row in at for s in row)]
    seeds = min(s.returns[a].size for row in at for s in row for a in actions)
    scores = {a: np.stack([np.stack([s.returns[a][:seeds] for s in row], axis=1)
                           / SUCCESS_BARS[t] for t, row in zip(tasks, at, strict=True)], axis=1)
              for a in actions}  # (seeds, tasks, steps)
    print(f"robust sample efficiency ({args.curve_reps:,} reps) ...")
    starts = ", ".join(
        f"{format_step(step)} {episodes_span(np.concatenate([row[i].episodes for row in at]))}"
        for i, step in enumerate(shared))
    point, interval = interval_estimates(scores, iqm_per_step, args.curve_reps, args.seed)
    report.figure(plot_sample_efficiency(
        np.array(shared, dtype=float), point, interval, scores, colors,
        f"IQM {SCORE_NAMES['success-bar'].lower()}", labels.get, f"Robust evaluation: "
        f"{', '.join(tasks)}, {seeds} seeds per task\nstarts per seed: {starts}"),
        "robust_sample_efficiency")
    for action in actions:
        for i, step in enumerate(shared):
            report.row("robust_sample_efficiency", "all", action, "IQM", step, seeds,
                       point[action][i], *interval[action][:, i])
    left_out = [t for t in barred if t not in curves]
    return ["", f"Over training (figure `robust_sample_efficiency`): each action's IQM of the "
            f"returns divided by each success bar, over {', '.join(tasks)} at "
            f"{', '.join(map(format_step, shared))}, {seeds} seeds per task"
            + (f"; {', '.join(left_out)} left out (evaluated at one step only)" if left_out
               else "") + "."]


# ------------------------------------------------------------------------- 4. over training
OVER_TRAINING_TABLE_STEPS = 11  # rows of summary.md's over-training table; summary.csv has all


def report_over_training(report: Report, analysis: Analysis) -> None:
    """Figure `over_training`: the paired differences and the measured shift at every shared
    step: how the mode's worth changes as the policy sharpens. Estimator: mean_curves (rliable's
    bootstrap of metrics.aggregate_mean at every step, --curve-reps) and the t-interval per step;
    the shift is the mean over runs with their range (a description, not an estimate)."""
    args, runs, tasks = analysis.args, analysis.runs, analysis.tasks
    differences = paired_difference_curves(tasks, analysis.pairing.derived)
    if not differences:
        return
    print(f"paired differences over training ({args.curve_reps:,} reps) ...")
    estimates = {task: mean_curves(by_group, args.curve_reps, args.seed)
                 for task, by_group in differences.items()}
    shifts = shift_curves(runs, tasks)
    names = {g: analysis.labels.action_first(g) for by_group in differences.values()
             for g in by_group}
    report.figure(plot_over_training({t: data.steps for t, data in tasks.items()}, differences,
                                     estimates, shifts, OVER_TRAINING_SHIFT_COLUMNS,
                                     analysis.colors, names, restart_marks(runs)),
                  "over_training")
    lines = ["At every step a task's runs share: the paired difference as in the headline "
             f"(bootstrap CI, {args.curve_reps:,} replications, and t-interval), and the shift "
             "measured at the states the mode policy visited (mean over runs). summary.csv has "
             f"every step; the table {OVER_TRAINING_TABLE_STEPS} of them.", ""]
    for task, by_group in differences.items():
        steps = tasks[task].steps
        shown = np.unique(np.linspace(0, steps.size - 1, OVER_TRAINING_TABLE_STEPS).round()
                          .astype(int))
        task_shift = shifts.get(task, {})
        table = []
        for i, step in enumerate(steps):
            cells = []
            for group, diffs in by_group.items():
                mean, (low, high) = estimates[task][group]
                report.row("paired_over_training", task, group, "return", int(step),
                           diffs.shape[0], mean[i], low[i], high[i])
                report.row("paired_over_training", task, group, "return_t", int(step),
                           diffs.shape[0], *t_interval(diffs[:, i]))
                cells += seed_cells(diffs[:, i], (mean[i], low[i], high[i]), 1)
            for column, values in task_shift.items():
                report.row("shift_over_training", task, CORRECTED, column, int(step),
                           values.shape[0], values[:, i].mean(), values[:, i].min(),
                           values[:, i].max())
                cells.append(f"{values[:, i].mean():.3f}")
            if i in shown:
                table.append([format_step(step), *cells])
        header = ["step", *(name for g in by_group
                            for name in (f"{g[1]} minus tanh(mu)", "t-interval")),
                  *task_shift]
        lines += [f"**{task}**", "", markdown_table(header, table), ""]
    report.section("Over training: paired differences and the measured shift", *lines)


# ---------------------------------------------------------- 5. q_best's choices (no figure)
def report_choice_shares(report: Report, analysis: Analysis) -> None:
    """q_best's choices (no figure): how often the critic picked each candidate at each task's
    scored step, for each action of CHOICE_SHARES. Estimator: the mean over seeds with the
    bootstrap CI (seed_mean_estimates), a share being one value per seed."""
    for action in CHOICE_SHARES:
        choice_shares_of(report, analysis, action)


def choice_shares_of(report: Report, analysis: Analysis, action: str) -> None:
    """One action's choice shares, where it was evaluated."""
    args, runs, tasks = analysis.args, analysis.runs, analysis.tasks
    samples = {((task, group), column): values for task, data in tasks.items()
               for group, curves in runs[task].items() if group[1] == action
               for column, values in logged_at(curves, CHOICE_SHARES[action],
                                               data.scored_step).items()}
    if not samples:
        return
    estimates = seed_mean_estimates(samples, args.reps, args.seed)
    prefix = f"{action}_share_"
    candidates = [column.removeprefix(prefix) for column in CHOICE_SHARES[action]]
    table = {}
    for ((task, group), column), values in samples.items():
        step = tasks[task].scored_step
        estimate = estimates[(task, group), column]
        name = column.removeprefix(prefix)
        report.row(f"{action}_share", task, group, name, step, values.size, *estimate)
        row = table.setdefault((task, group), [task, format_step(step),
                                               analysis.labels.algorithm(group[0]),
                                               values.size, *["-"] * len(candidates)])
        row[4 + candidates.index(name)] = interval_text(*estimate)
    report.section(
        f"{action}: which action the critic picked",
        f"Share of {action}'s evaluation steps at which the critic preferred each "
        "candidate, at each task's scored step; mean over seeds with a 95% bootstrap CI.", "",
        markdown_table(["task", "step", "algorithm", "seeds",
                        *(ACTIONS.get(c, c) for c in candidates)], list(table.values())))


# ------------------------------------------------- 6. reward curves and final returns (Fig. 5)
def report_reward_curves(report: Report, analysis: Analysis) -> None:
    """Figure 5 (`reward_curves`) and the per-task final returns. Estimators: the curves,
    mean_curves (the t-interval up to FEW_SEEDS seeds); the final returns, the mean over seeds
    with the bootstrap CI (seed_mean_estimates), raw and normalised."""
    args, tasks, norms = analysis.args, analysis.tasks, analysis.norms
    groups, colors, labels = analysis.groups, analysis.colors, analysis.labels
    print(f"per-task curves ({args.curve_reps:,} reps) and final returns ({args.reps:,}) ...")
    curves = {t: mean_curves(data.returns, args.curve_reps, args.seed, FEW_SEEDS)
              for t, data in tasks.items()}
    styles = {(t, g): ":" if one_episode_per_seed(analysis.runs[t].get(g, []), data.steps)
              else "-" if is_own(g) else "--" for t, data in tasks.items() for g in data.returns}
    seeds = sorted({r.shape[0] for data in tasks.values() for r in data.returns.values()})
    interval = "t-interval" if seeds[-1] <= FEW_SEEDS else "bootstrap CI" \
        if seeds[0] > FEW_SEEDS else f"t-interval (<= {FEW_SEEDS} seeds), else bootstrap CI"
    report.figure(plot_reward_curves(
        {t: data.steps for t, data in tasks.items()},
        {t: {g: curves[t][g] for g in groups if g in data.returns} for t, data in tasks.items()},
        colors, labels, styles, SUCCESS_BARS,
        f"Mean evaluation return over {' or '.join(map(str, seeds))} "
        f"seed{'' if seeds == [1] else 's'}, 95% {interval}",
        restart_marks(analysis.runs)), "reward_curves")
    finals = seed_mean_estimates({(t, g): data.scored(g) for t, data in tasks.items()
                                  for g in data.returns}, args.reps, args.seed)
    table = []
    for task, data in tasks.items():
        for group in [g for g in groups if g in data.returns]:
            point, low, high = finals[task, group]
            runs, step = data.returns[group].shape[0], data.scored_step
            scores = normalize(np.array([point, low, high]), norms[task])
            report.row("task_final", task, group, "return", step, runs, point, low, high)
            report.row("task_final", task, group, "score", step, runs, *scores)
            table.append([task, format_step(step), labels(group), runs,
                          interval_text(point, low, high, 1, runs),
                          interval_text(*scores, runs=runs)])
    report.section("Final evaluation return per task (mean over seeds, 95% CI)",
                   markdown_table(["task", "step", "group", "seeds", "return", "score"], table))


# ------------------------------------------------------------ 7. aggregate metrics (Fig. 6)
def report_aggregate_metrics(report: Report, analysis: Analysis) -> None:
    """Figure 6 (`aggregate_metrics`) and its table: IQM, median, mean and optimality gap of the
    normalised final scores over the tasks every algorithm ran. Estimator: aggregate_estimates,
    rliable's stratified bootstrap (runs resampled within each fixed task), as the paper has it;
    IQM first, robust to outlying runs yet using half of them."""
    agg, args = analysis.aggregate, analysis.args
    if agg is None:
        return
    score_name = SCORE_NAMES[args.normalize]
    names = AGGREGATE_METRICS if args.normalize != "none" else AGGREGATE_METRICS[:3]
    print(f"aggregate metrics over {len(agg.tasks)} task(s) ({args.reps:,} reps) ...")
    note = iqm_note(sorted({scores.shape[0] for scores in agg.final.values()}), len(agg.tasks))
    point, interval = aggregate_estimates(agg.final, len(names) == len(AGGREGATE_METRICS),
                                          args.reps, args.seed)
    report.figure(plot_aggregate_metrics(point, interval, agg.final, names, analysis.colors,
                                         score_name, analysis.labels, note), "aggregate_metrics")
    table = []
    for g in agg.groups:
        runs = agg.final[g].shape[0]
        for i, name in enumerate(names):
            report.row("aggregate", "all", g, name, "", runs, point[g][i], *interval[g][:, i])
        table.append([analysis.labels(g), runs, *[interval_text(
            point[g][i], *interval[g][:, i], runs=runs) for i in range(len(names))]])
    report.section(f"Aggregate metrics over {len(agg.tasks)} task(s)",
                   f"{score_name}s at each task's scored step; tasks: {', '.join(agg.tasks)}."
                   + (f" {note}." if note else ""),
                   "", markdown_table(["group", "runs per task", *names], table))


# ---------------------------------------------------------- 8. performance profiles (Fig. 7)
def report_performance_profiles(report: Report, analysis: Analysis) -> None:
    """Figure 7 (`performance_profiles`; no table): the share of runs scoring above tau, the
    whole distribution of the final scores. Estimator: performance_profiles (rliable's, with
    its stratified-bootstrap CIs, --curve-reps)."""
    agg, args = analysis.aggregate, analysis.args
    if agg is None:
        return
    print(f"performance profiles ({args.curve_reps:,} reps) ...")
    taus = profile_thresholds(agg.final)
    profiles = performance_profiles(agg.final, taus, args.curve_reps, args.seed)
    report.figure(plot_performance_profiles(taus, *profiles, agg.final, analysis.colors,
                                            SCORE_NAMES[args.normalize], analysis.labels,
                                            aggregate_title(agg)), "performance_profiles")


# ------------------------------------------------------------ 9. sample efficiency (Fig. 8)
def report_sample_efficiency(report: Report, analysis: Analysis) -> None:
    """Figure 8 (`sample_efficiency`; no table): the aggregate IQM against steps, or fractions
    of each task's budget (build_aggregate's frames). Estimator: interval_estimates of
    iqm_per_step (metrics.aggregate_iqm at every frame at once), --curve-reps."""
    agg, args = analysis.aggregate, analysis.args
    if agg is None:
        return
    if agg.frames.size == 1:
        where = f"{agg.frames[0]:g} of the budget" if agg.by_fraction \
            else format_step(agg.frames[0])
        report.notes.append(
            "sample-efficiency curve left out: the aggregated tasks share one evaluation point "
            f"({where}), so its axis would hold a single step")
    elif agg.frames.size:
        print(f"sample-efficiency curves ({args.curve_reps:,} reps) ...")
        point, interval = interval_estimates(agg.curves, iqm_per_step, args.curve_reps,
                                             args.seed)
        report.figure(plot_sample_efficiency(
            agg.frames, point, interval, agg.curves, analysis.colors,
            f"IQM {SCORE_NAMES[args.normalize].lower()}", analysis.labels, aggregate_title(agg),
            agg.by_fraction), "sample_efficiency")


# -------------------------------------------------------- 10. probability of improvement
def report_probability_of_improvement(report: Report, analysis: Analysis) -> None:
    """Figure `probability_of_improvement` and its paragraph: P(corrected > standard) on a task
    drawn at random. Estimator: interval_estimates of metrics.probability_of_improvement
    (Mann-Whitney per task, averaged over tasks), as the paper has it; it ignores the pairing."""
    agg, args, labels = analysis.aggregate, analysis.args, analysis.labels
    if agg is None:
        return
    x, y = COMPARISON
    if x not in agg.groups or y not in agg.groups:
        report.notes.append(f"probability of improvement needs both {group_name(x)} and "
                            f"{group_name(y)} runs: skipped")
        return
    print(f"probability of improvement ({args.curve_reps:,} reps) ...")
    pair = f"{group_name(x)} > {group_name(y)}"
    point, interval = interval_estimates({pair: [agg.final[x], agg.final[y]]},
                                         metrics.probability_of_improvement,
                                         args.curve_reps, args.seed)
    low, high = interval[pair].ravel()
    runs = f"{agg.final[x].shape[0]} vs {agg.final[y].shape[0]}"
    fewest = min(agg.final[g].shape[0] for g in (x, y))
    report.row("probability_of_improvement", "all", pair, "P(X > Y)", "", runs, point[pair],
               low, high)
    report.figure(plot_probability_of_improvement(point[pair], (low, high), x, y,
                                                  analysis.colors[x], labels),
                  "probability_of_improvement")
    report.section("Probability of improvement",
                   f"P({labels(x)} > {labels(y)}) = "
                   f"{interval_text(point[pair], low, high, runs=fewest)}: the "
                   f"chance that a run of {labels(x)} scores higher than a run of {labels(y)} on "
                   "a task drawn at random (Mann-Whitney per task, averaged over tasks). It "
                   "compares every run of one with every run of the other and so ignores the "
                   "pairing (the same seed's actors from the same start states); the paired "
                   "comparison is the headline's.")


# ---------------------------------------------------------------------- 11. the dimension study
def report_dimension_study(report: Report, analysis: Analysis) -> None:
    """Beyond the paper (figure `dimension_study`): what each evaluation action is worth as the
    action dimension grows, one task per dimension (build_study). Estimator: the mean over seeds
    with the bootstrap CI (seed_mean_estimates) of each paired difference, normalised by the
    range of the task's tanh(mu) returns, and of the measured shift; the t-interval of the raw
    difference beside it. Tasks are not pooled: each point is a different task."""
    study, notes = build_study(analysis.runs, analysis.tasks, analysis.pairing.derived)
    report.notes.extend(notes)
    args, labels = analysis.args, analysis.labels
    dims = sorted({d.action_dim for d in study.values()})
    if len(dims) < 2:
        report.notes.append(
            "dimension study skipped: it needs paired evaluations against tanh(mu) (corrected "
            "runs, or runs made with --eval-selectors) on tasks of at least two different "
            f"action dimensions; found {'only ' + str(dims) if dims else 'none'}")
        return
    print(f"dimension study over {len(study)} tasks ({args.reps:,} reps) ...")
    study = dict(sorted(study.items(), key=lambda item: (item[1].action_dim, item[0])))
    samples = {((t, g), f): by_fraction[f] / d.scale for t, d in study.items()
               for g, by_fraction in d.differences.items() for f in d.steps}
    samples |= {(t, column): v for t, d in study.items() for column, v in d.shift.items()}
    estimates = seed_mean_estimates(samples, args.reps, args.seed)
    table, shift_table = [], []
    for task, d in study.items():
        for group in d.differences:
            for f, step in d.steps.items():
                diffs, boot = d.differences[group][f], estimates[(task, group), f]
                raw, t_values = [v * d.scale for v in boot], t_interval(diffs)
                for metric, values in (("normalised_difference", boot), ("raw_difference", raw),
                                       ("normalised_difference_t", [v / d.scale for v in t_values]),
                                       ("raw_difference_t", t_values)):
                    report.row("dimension", task, group, f"{metric}@{f:g}", step, diffs.size,
                               *values)
                table.append([task, d.action_dim, labels.algorithm(group[0]), group[1],
                              diffs.size, f"{f:g} ({format_step(step)})",
                              *seed_cells(diffs, raw, 1), seed_cells(diffs / d.scale, boot)[0],
                              above_zero(diffs)])
        for column, values in d.shift.items():
            report.row("dimension_shift", task, "corrected", column, d.steps[1.0], values.size,
                       *estimates[task, column])
        shift_table.append([task, d.action_dim, *(interval_text(*estimates[task, c])
                                                  if c in d.shift else "-"
                                                  for c in DIMENSION_SHIFT_COLUMNS)])
    colors = sns.color_palette("viridis", n_colors=len(study))
    report.figure(plot_dimension_study(study, estimates, colors, labels, list(ACTIONS)),
                  "dimension_study")
    report.section(
        "Beyond the paper: the paired difference against the action dimension",
        "Each evaluation action (the mode, and where logged the mean and q_best) minus tanh(mu) "
        "of the same actors, per seed, at fractions of each task's shared steps; normalised by "
        "the range of the task's tanh(mu) returns in this folder (all seeds and steps), so that "
        "tasks compare; mean over seeds with a 95% bootstrap CI, and the raw difference's "
        "t-interval. Raw numbers are in summary.csv (section `dimension`). Each dimension is a "
        "different task, with its own body and reward: the points compare tasks, they are not "
        "one task swept over its action dimension.", "",
        markdown_table(["task", "action dims", "algorithm", "action", "seeds", "fraction (step)",
                        "raw difference (bootstrap CI)", "t-interval", "normalised difference",
                        "above zero"], table), "",
        "Measured shift at the final step (eval.csv, over the states the mode policy visited; "
        "mean over seeds with a 95% bootstrap CI), beside the theory curve of mode_search.py "
        "(figure, last row):", "",
        markdown_table(["task", "action dims", *DIMENSION_SHIFT_COLUMNS], shift_table))


# ------------------------------------------------------------------- 12. the robust dimension study
def short_task(task: str) -> str:
    """A tick's task name: h1hand-cube-v0 as cube, Hopper-v5 as Hopper."""
    return task.removeprefix("h1hand-").rsplit("-v", 1)[0]


def report_robust_dimension(report: Report, analysis: Analysis) -> None:
    """Figure `robust_dimension` (only with --robust, over tasks of two or more action
    dimensions): the dimension study on the robust evaluations, each task at its last robust
    step (robust_dimension_study). Estimator: per seed, the action's paired difference as a
    share of that seed's tanh(mu) return; over seeds, the mean with Student's t-interval and,
    labelled, the bootstrap (seed_mean_estimates). Tasks are not pooled."""
    if analysis.robust is None:
        return
    args = analysis.args
    by_task = robust_paired_differences(analysis.robust)
    study, notes = robust_dimension_study(by_task, analysis.runs)
    if len({d.action_dim for d in study.values()}) < 2:
        return  # one task's or one body's campaign: nothing to set against the dimension
    report.notes.extend(notes)
    study = dict(sorted(study.items(), key=lambda item: (item[1].action_dim, item[0])))
    estimates = seed_mean_estimates({(t, a): v for t, d in study.items()
                                     for a, v in d.relative.items()}, args.reps, args.seed)
    table, cells, ticks, disagree = [], {}, [], []
    for i, (task, d) in enumerate(study.items()):
        at = by_task[task][d.step]
        ticks.append(f"{short_task(task)}\n{d.action_dim} dims\n{format_step(d.step)}, "
                     f"{at.episodes.size} x {episodes_span(at.episodes)}")
        tanh_mu = at.returns[BASELINE]
        for action, relative in d.relative.items():
            boot, t_values = estimates[task, action], t_interval(relative)
            for metric, values in (("relative_difference", boot),
                                   ("relative_difference_t", t_values)):
                report.row("robust_dimension", task, action, metric, d.step, relative.size,
                           *values)
            table.append([task, d.action_dim, format_step(d.step), action, relative.size,
                          f"{tanh_mu.mean():.1f}",
                          *seed_cells(100 * relative, [100 * v for v in boot], 1),
                          verdict_counts(at.differences[action], at.errors[action])])
            cells[i, action] = PairedCell(100 * relative, [100 * v for v in boot],
                                          [100 * v for v in t_values],
                                          100 * at.errors[action] / tanh_mu, seeds=at.seeds)
            # Dividing by each seed's return weighs the seeds differently, so the shares'
            # interval can exclude zero where the returns' (the task's verdict) does not.
            returns_t = t_interval(at.differences[action])
            if excludes_zero(t_values) != excludes_zero(returns_t):
                disagree.append(f"{short_task(task)} {action}: shares {100 * t_values[1]:+.1f}% "
                                f"to {100 * t_values[2]:+.1f}%, returns {returns_t[1]:+.3g} to "
                                f"{returns_t[2]:+.3g}")
    labels, colors = robust_labels_colors(analysis.robust.actions)
    row = PairedRow("Against the action dimension: each x a different task (its own body and "
                    "reward),\nat its last robust step (seeds x starts); intervals of shares, "
                    "not a task's verdict (summary.md)", ticks, cells,
                    "minus tanh(mu), % of its return")
    report.figure(plot_paired([row], colors, labels, "the robust evaluation, as a share of "
                              "each seed's tanh(mu) return"), "robust_dimension")
    report.section(
        "Beyond the paper: the robust evaluation against the action dimension",
        "Each task at its last robust step: per seed, each action's paired difference from the "
        "same starts divided by that seed's tanh(mu) return; over seeds, the mean (in %) with "
        f"rliable's bootstrap ({args.reps:,} replications) and Student's 95% t-interval; "
        f"'ahead / level / behind': seeds beyond {VERDICT_SE:g} standard errors of their paired "
        "episodes. Each dimension is a different task, with its own body and reward: the points "
        "compare tasks, they are not one task swept over its action dimension. A task's "
        "verdict is the t-interval of its return differences (the robust evaluation's "
        "section), not of these shares"
        + ("; the two disagree on whether zero is inside for " + "; ".join(disagree) + "."
           if disagree else ", and here the two agree on whether zero is inside."),
        *few_seeds_lines([v.size for d in study.values() for v in d.relative.values()]), "",
        markdown_table(["task", "action dims", "step", "action", "seeds", "tanh(mu)'s return",
                        "minus tanh(mu), % of its return (bootstrap CI)", "t-interval",
                        "ahead / level / behind"], table))


# ============================================================================== the pipeline
REPORT_SECTIONS: tuple[Callable[[Report, Analysis], None], ...] = (
    report_standard_provenance,
    report_paired_difference,
    report_robust_evaluation,
    report_over_training,
    report_choice_shares,
    report_reward_curves,
    report_aggregate_metrics,
    report_performance_profiles,
    report_sample_efficiency,
    report_probability_of_improvement,
    report_dimension_study,
    report_robust_dimension,
)


def validate(args: Args) -> None:
    """Every flag's valid range, checked before anything is read or written."""
    if not args.runs_dirs:
        raise AnalysisError("no folder given: analyze.py RUNS [RUNS ...] --out REPORT, RUNS the "
                            "folder(s) holding the run folders")
    rules = (
        ("reps", args.reps >= 1, "at least 1"),
        ("curve_reps", args.curve_reps >= 1, "at least 1"),
        ("curve_points", args.curve_points >= 2, "at least 2"),
        ("at_step", args.at_step is None or args.at_step >= 1, "a step of at least 1"),
        ("seed", 0 <= args.seed < 2**32, "in [0, 2**32) (NumPy's seed range)"),
        ("format", len(args.format) >= 1, "one or more of png, pdf"),
    )
    if message := broken_rule(args, rules):
        raise AnalysisError(message)


def analyze(args: Args) -> Report:
    """The data (load, pair, align, normalise) once, then REPORT_SECTIONS in summary.md's order,
    then summary.md and summary.csv."""
    validate(args)
    runs, notes = load_runs(args.runs_dirs)
    robust = load_robust(args.robust) if args.robust else None
    pairing = standard_from_paired(runs)
    groups = ordered_groups(runs)
    found = found_text(args.runs_dirs, runs, groups)
    print(found + "\n")
    tasks, align_notes = align(runs, args.at_step)
    normalization, chosen = resolve_normalization(args.normalize, list(tasks))
    args = dataclasses.replace(args, normalize=normalization)
    norms = normalizers(tasks, args.normalize)
    aggregate, aggregate_notes = build_aggregate(tasks, norms, groups, args.curve_points)
    analysis = Analysis(args, runs, tasks, groups, pairing, norms, aggregate,
                        GroupLabels(standard_label(pairing, list(runs))), group_colors(groups),
                        robust)
    args.out.mkdir(parents=True, exist_ok=True)
    report = Report(args.out, args.format, notes=notes + align_notes + aggregate_notes,
                    names=group_name)
    for section in REPORT_SECTIONS:
        section(report, analysis)
    report.write(summary_header(analysis, chosen, found))
    return report


def main(argv: Sequence[str] | None = None) -> int:
    args = tyro.cli(Args, args=argv, description=__doc__.split("\n\n")[0])
    matplotlib.use("Agg")  # figures only go to files: no display needed
    try:
        analyze(args)
    except AnalysisError as error:
        print(f"analyze.py: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
