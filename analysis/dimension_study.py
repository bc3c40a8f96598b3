"""Beyond the paper: each evaluation action's paired difference against the action dimension,
one task per dimension (analyze.py's last report section; the classic tasks of
`sweep.py --preset dimensions` give it several dimensions). Each point is a different task, with
its own body and reward, not one task swept over its action dimension.

Built from analyze.py's data (analysis/data.py; `build_study`: a `Dimension` per task),
then estimated, tabulated and drawn here: summary.csv's sections `dimension` and
`dimension_shift`, figure `dimension_study`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import seaborn as sns

from analysis import estimators
from analysis.data import Curve, Runs, Task, group_rank, own_action, paired_groups, paired_values
from analysis.report import Report, above_zero, format_ci, format_step, markdown_table, seed_cells

# Measured at the states the mode policy visited (sac_corrected.py's eval.csv).
SHIFT_COLUMNS = ("mode_shift_abs_sum", "sigma_mean", "bimodal_fraction")
# Paired differences at these fractions of each task's shared steps.
TRAINING_FRACTIONS = (0.25, 0.5, 0.75, 1.0)


@dataclasses.dataclass
class Dimension:
    """One task of the dimension study: its action dimension, the per-seed paired difference of
    each evaluation action (minus tanh(mu)) at fractions of training, and the shift measured at
    its final step."""

    action_dim: int
    scale: float  # the range of the task's tanh(mu) returns in the folder
    steps: dict[float, int]  # training fraction -> step
    # group -> fraction -> per-seed raw difference, groups in the report's order
    differences: dict[tuple[str, str], dict[float, np.ndarray]]
    shift: dict[str, np.ndarray]  # SHIFT_COLUMN -> per-seed value at the final step (logged ones)


def training_fraction_steps(steps: np.ndarray, scored_step: int) -> dict[float, int]:
    """The shared step at each of TRAINING_FRACTIONS: the last one at or before that share of
    the scored step (the first shared step if none is), the scored step at 1.0."""
    picks = {f: int(steps[max(0, np.searchsorted(steps, f * scored_step, side="right") - 1)])
             for f in TRAINING_FRACTIONS}
    return {**picks, 1.0: scored_step}


def shift_at(curves: list[Curve], step: int) -> dict[str, np.ndarray]:
    """Each SHIFT_COLUMN at `step`, one value per run that logged it (empty cells left out)."""
    shift = {}
    for column in SHIFT_COLUMNS:
        values = np.array([c.shift[column][c.steps == step][0]
                           for c in curves if column in c.shift])
        if np.isfinite(values).any():
            shift[column] = values[np.isfinite(values)]
    return shift


def build_study(runs: Runs, tasks: dict[str, Task], derived: Sequence[str]
                ) -> tuple[dict[str, Dimension], list[str]]:
    """Each evaluation action's paired difference and the measured shift per task, keyed by
    action dimension, and notes on the tasks left out."""
    study, notes = {}, []
    for task, data in tasks.items():
        pairs = paired_groups(data, task in derived)
        if not pairs:
            continue
        algorithms = {group[0] for group, _ in pairs}
        dims = {c.action_dim for a in algorithms for c in runs[task].get((a, own_action(a)), [])}
        if None in dims or len(dims) != 1:
            notes.append(f"{task}: its runs' config.json give no single action_dim "
                         f"({sorted(dims, key=str)}); left out of the dimension study")
            continue
        baselines = np.concatenate([data.returns[b].ravel() for b in {b for _, b in pairs}])
        scale = float(baselines.max() - baselines.min()) or 1.0
        steps = training_fraction_steps(data.steps, data.scored_step)
        differences = {}
        for group, baseline in pairs:
            own, paired = paired_values(data, group, baseline, np.array(list(steps.values())))
            differences[group] = dict(zip(steps, (own - paired).T, strict=True))
        shift = {}
        for key in sorted(((a, own_action(a)) for a in algorithms), key=group_rank):
            shift = shift or shift_at(runs[task][key], data.scored_step)
        study[task] = Dimension(dims.pop(), scale, steps, differences, shift)
    return study, notes


def dimension_estimates(study: dict[str, Dimension], reps: int, seed: int) -> dict:
    """Mean over seeds with its bootstrap CI (rliable), (mean, low, high): keyed
    ((task, group), fraction) for the normalised paired difference, (task, column) for the
    measured shift."""
    samples = {((t, g), f): by_fraction[f] / d.scale for t, d in study.items()
               for g, by_fraction in d.differences.items() for f in d.steps}
    samples |= {(t, column): v for t, d in study.items() for column, v in d.shift.items()}
    return estimators.seed_mean_estimates(samples, reps, seed)


def dimension_positions(study: dict[str, Dimension]) -> dict[str, float]:
    """Each task's x on the log dimension axis: its action dimension, tasks that share one
    spread a little around it so that their CIs do not hide each other."""
    positions = {}
    for dim in {d.action_dim for d in study.values()}:
        same = [t for t, d in study.items() if d.action_dim == dim]
        for k, task in enumerate(same):
            positions[task] = dim * 1.07 ** (k - (len(same) - 1) / 2)
    return positions


def _errorbar(ax, x: float, estimate: tuple[float, float, float], **style) -> None:
    point, low, high = estimate
    ax.errorbar(x, point, yerr=[[point - low], [high - point]], capsize=3, **style)


def study_actions(study: dict[str, Dimension], order: Sequence[str]) -> list[str]:
    """The evaluation actions compared with tanh(mu) in the study, in `order` (mode, mean,
    q_best), then any other."""
    found = {g[1] for d in study.values() for g in d.differences}
    known = [a for a in order if a in found]
    return known + sorted(found - set(known))


def plot_dimension_study(study: dict[str, Dimension], estimates: dict, colors: list,
                         labels, order: Sequence[str]) -> plt.Figure:
    """Per evaluation action, a row: its paired difference against the action dimension and
    against training; last row: the measured shift beside mode_search's theory curve, and
    sigma / bimodal share against the dimension."""
    from mode_search import SPREADS, summed_shift_by_dimension  # torch: only for this figure

    actions = study_actions(study, order)
    fig, axes = plt.subplots(len(actions) + 1, 2, figsize=(13, 4.75 * (len(actions) + 1)),
                             squeeze=False)
    (ax_shift, ax_sigma) = axes[-1]
    ax_bimodal = ax_sigma.twinx()
    xs = dimension_positions(study)
    markers = {"corrected": "o", "standard": "s"}
    for (ax_dim, ax_progress), action in zip(axes[:-1], actions, strict=True):
        groups = {g for d in study.values() for g in d.differences if g[1] == action}
        several = len({g[0] for g in groups}) > 1
        for (task, d), color in zip(study.items(), colors, strict=False):
            for group in d.differences:
                if group[1] != action:
                    continue
                name = f"{task} ({d.action_dim})" + (f", {labels.algorithm(group[0])}"
                                                     if several else "")
                _plot_difference(ax_dim, ax_progress, xs[task], d, estimates, (task, group),
                                 color=color, marker=markers.get(group[0], "D"),
                                 label=name)
        ylabel = f"{action} - tanh(mu), normalised"
        ax_dim.set(xscale="log", xlabel="action dimensions", ylabel=ylabel,
                   title=f"{action}: paired difference, final step (95% CI); hollow: 25/50/75%")
        ax_progress.set(xlabel="fraction of training", ylabel=ylabel,
                        title=f"{action}: ... as training goes on")
        for ax in (ax_dim, ax_progress):
            ax.axhline(0, color="0.4", ls=":", lw=1)
        ax_dim.legend(fontsize=7)
    for (task, d), color in zip(study.items(), colors, strict=False):
        if "mode_shift_abs_sum" in d.shift:
            _errorbar(ax_shift, xs[task], estimates[task, "mode_shift_abs_sum"], fmt="o",
                      color=color, zorder=3)
        if "sigma_mean" in d.shift:
            _errorbar(ax_sigma, xs[task], estimates[task, "sigma_mean"], fmt="o", color=color)
        if "bimodal_fraction" in d.shift:
            _errorbar(ax_bimodal, xs[task], estimates[task, "bimodal_fraction"], fmt="s",
                      mfc="none", color=color)
    top = max(d.action_dim for d in study.values())
    n = np.arange(1, top + 1)
    for i, ((name, spread), color) in enumerate(zip(SPREADS.items(), ("0.3", "0.6"),
                                                    strict=True)):
        mean, low, high = (t.numpy() for t in summed_shift_by_dimension(top, spread, seed=i))
        ax_shift.plot(n, mean, color=color, lw=1, label=f"theory, {name}")
        ax_shift.fill_between(n, low, high, color=color, alpha=0.15)
    ax_shift.set(xscale="log", yscale="log", xlabel="action dimensions",
                 ylabel="sum |mode - tanh(mu)| at visited states",
                 title="Measured shift at the final step (95% CI) and theory (mode_search)")
    ax_sigma.set(xscale="log", xlabel="action dimensions", ylabel="sigma_mean (dots)",
                 title="Policy sigma and share of bimodal dimensions at the final step")
    ax_bimodal.set(ylabel="bimodal_fraction (squares)", ylim=(-0.02, 1.02))
    dims = sorted({d.action_dim for d in study.values()})
    for ax in (*axes[:-1, 0], ax_shift, ax_sigma):  # label the dimensions themselves, not decades
        ax.set_xticks(dims, [str(d) for d in dims])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    for ax in axes.flat:
        ax.grid(alpha=0.25)
    ax_shift.legend(fontsize=7, loc="upper left")
    fig.suptitle("Each point is a different task (its own body, reward and action dimension), "
                 "not one task swept over the dimension", fontsize="large")
    fig.tight_layout()
    return fig


def _plot_difference(ax_dim, ax_progress, x: float, d: Dimension, estimates: dict,
                     key: tuple[str, str], color, marker: str, label: str) -> None:
    """One (task, evaluation action): final step with CI and earlier fractions hollow against
    the dimension; the mean with its CI band against the fraction of training."""
    fractions = sorted(d.steps)
    _errorbar(ax_dim, x, estimates[key, 1.0], fmt=marker, color=color, ms=7, label=label)
    for f in fractions[:-1]:  # earlier in training: hollow, fainter the earlier
        ax_dim.plot(x, estimates[key, f][0], marker, mfc="none", color=color,
                    alpha=0.25 + 0.6 * f, ms=4 + 3 * f)
    ax_progress.plot(fractions, [estimates[key, f][0] for f in fractions], f"{marker}-",
                     color=color, label=label)
    ax_progress.fill_between(fractions, [estimates[key, f][1] for f in fractions],
                             [estimates[key, f][2] for f in fractions], color=color, alpha=0.15)


def report_study(report: Report, study: dict[str, Dimension], labels, order: Sequence[str],
                 reps: int, seed: int) -> None:
    """Beyond the paper (figure `dimension_study`): what each evaluation action is worth as the
    action dimension grows, one task per dimension. Estimator: the mean over seeds with
    rliable's bootstrap CI (seed_mean_estimates: estimators.bootstrap_mean) of
    each task's per-seed paired difference, normalised by the range of its tanh(mu) returns so
    that tasks of different reward scales share an axis, and of the measured shift; beside it
    Student's t-interval of the raw difference (few seeds). Tasks are not pooled: each point is
    a different task. `labels`: the report's group labels; `order`: the actions' order."""
    dims = sorted({d.action_dim for d in study.values()})
    if len(dims) < 2:
        report.notes.append(
            "dimension study skipped: it needs paired evaluations against tanh(mu) (corrected "
            "runs, or runs made with --eval-selectors) on tasks of at least two different "
            f"action dimensions; found {'only ' + str(dims) if dims else 'none'}")
        return
    print(f"dimension study over {len(study)} tasks ({reps:,} reps) ...")
    study = dict(sorted(study.items(), key=lambda item: (item[1].action_dim, item[0])))
    estimates = dimension_estimates(study, reps, seed)
    table, shift_table = [], []
    for task, d in study.items():
        for group in d.differences:
            for f, step in d.steps.items():
                diffs = d.differences[group][f]
                runs_n = diffs.size
                point, low, high = estimates[(task, group), f]
                report.row("dimension", task, group, f"normalised_difference@{f:g}", step,
                           runs_n, point, low, high)
                report.row("dimension", task, group, f"raw_difference@{f:g}", step, runs_n,
                           *(v * d.scale for v in (point, low, high)))
                t_values = estimators.t_interval(diffs)
                report.row("dimension", task, group, f"normalised_difference_t@{f:g}", step,
                           runs_n, *(v / d.scale for v in t_values))
                report.row("dimension", task, group, f"raw_difference_t@{f:g}", step, runs_n,
                           *t_values)
                raw, t_cell = seed_cells(diffs, [v * d.scale for v in (point, low, high)], 1)
                table.append([task, d.action_dim, labels.algorithm(group[0]), group[1],
                              runs_n, f"{f:g} ({format_step(step)})", raw, t_cell,
                              seed_cells(diffs / d.scale, (point, low, high))[0],
                              above_zero(diffs)])
        for column, values in d.shift.items():
            report.row("dimension_shift", task, "corrected", column, d.steps[1.0], values.size,
                       *estimates[task, column])
        shift_table.append([task, d.action_dim, *(format_ci(*estimates[task, c]) if c in d.shift
                                                  else "-" for c in SHIFT_COLUMNS)])
    colors = sns.color_palette("viridis", n_colors=len(study))
    report.figure(plot_dimension_study(study, estimates, colors, labels, order),
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
        markdown_table(["task", "action dims", *SHIFT_COLUMNS], shift_table))


# ============================================================================== the pipeline
