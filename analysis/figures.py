"""Every figure analyze.py draws: plain functions from arrays, labels and colours to a figure;
the numbers come from analyze.py's report sections, which save them."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch
from rliable import plot_utils

from analysis import estimators
from analysis.data import Dimension
from analysis.report import counted


def steps_axis(max_step: float) -> tuple[float, str]:
    """A figure's step axis: the unit steps are divided by, and its label."""
    if max_step >= 1e6:
        return 1e6, "Environment steps (millions)"
    if max_step >= 1e3:
        return 1e3, "Environment steps (thousands)"
    return 1.0, "Environment steps"


# ------------------------------------------------------- the paper's figures (rliable's plots)
CURVE_STYLE = {"labelsize": "large", "ticklabelsize": "large", "legend": True,
               "legendsize": "large"}  # Figures 7 and 8's text and legend


def by_label(values: dict, labels: Callable[[object], str]) -> dict:
    """rliable's plots key each group by its label."""
    return {labels(g): v for g, v in values.items()}


def curve_axes(title: str, scores: dict) -> tuple[plt.Figure, plt.Axes]:
    """Figures 7 and 8's axes, titled with `title` and band_line."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.set_title(f"{title}\n{band_line(scores, 'bands')}", fontsize="medium")
    return fig, ax


def band_line(scores: dict[object, np.ndarray], band: str) -> str:
    """A figure's line on what its `band` shows: stratified-bootstrap CIs over how many runs and
    tasks, and, from FEW_SEEDS runs or fewer, that they are too narrow."""
    runs = sorted({values.shape[0] for values in scores.values()})
    tasks = next(iter(scores.values())).shape[1]
    line = (f"{band}: {estimators.CONFIDENCE:.0%} stratified-bootstrap CIs (rliable), "
            f"{counted(' or '.join(map(str, runs)), 'run')} x {counted(tasks, 'task')}")
    return line + (";\nfrom this few runs they are narrower than the data allow"
                   if runs[0] <= estimators.FEW_SEEDS else "")


def plot_aggregate_metrics(point: dict, interval: dict, scores: dict, names: Sequence[str],
                           colors: dict, xlabel: str, labels: Callable[[str], str],
                           note: str = "") -> plt.Figure:
    """Figure 6: aggregate metrics with their CIs (rliable's plot), `note` and band_line below."""
    note = "\n".join(filter(None, [note, band_line(scores, "bars")]))
    # rliable's defaults (4 ticks at xx-large on 3.4-inch panels, its x label a fixed share of
    # the height below) make tick labels collide with each other and, with two groups, with the
    # label: wider panels, smaller ticks, a figure at least 2.2 inches high, the label placed
    # in inches.
    height = max(0.55 * len(point), 2.2)
    fig, axes = plot_utils.plot_interval_estimates(
        by_label(point, labels), by_label(interval, labels), metric_names=list(names),
        algorithms=[labels(g) for g in point], colors={labels(g): colors[g] for g in point},
        xlabel=xlabel, row_height=height / len(point), xlabel_y_coordinate=-0.6 / height,
        max_ticks=4, subfigure_width=4.0, wspace=0.2)
    for ax in np.atleast_1d(axes):
        ax.tick_params(axis="x", labelsize="x-large")
    if note:
        fig.text(0.4, -1.0 / height, note, ha="center", va="top", fontsize="x-large",
                 color="0.3")
    return fig


def profile_thresholds(final: dict[str, np.ndarray]) -> np.ndarray:
    """The profile's 101 values of tau over the scores' own range (from 0 where all are
    positive), not the bar's: scores a fraction of the bar would crowd the axis's left."""
    everything = np.concatenate([s.ravel() for s in final.values()])
    low, high = min(everything.min(), 0.0), everything.max()
    return np.linspace(low, high + (0.05 * (high - low) or 0.05), 101)


def plot_performance_profiles(taus: np.ndarray, profiles: dict, cis: dict, scores: dict,
                              colors: dict, xlabel: str, labels: Callable[[str], str], title: str
                              ) -> plt.Figure:
    """Figure 7: performance profiles (share of runs scoring above tau) of `scores` with CIs."""
    fig, ax = curve_axes(title, scores)
    plot_utils.plot_performance_profiles(
        by_label(profiles, labels), taus, performance_profile_cis=by_label(cis, labels),
        colors={labels(g): colors[g] for g in profiles}, xlabel=rf"{xlabel} ($\tau$)", ax=ax,
        **CURVE_STYLE)
    return fig


def plot_sample_efficiency(frames: np.ndarray, point: dict, interval: dict, scores: dict,
                           colors: dict, ylabel: str, labels: Callable[[str], str], title: str,
                           by_fraction: bool = False) -> plt.Figure:
    """Figure 8: aggregate IQM against steps (or fractions of each task's budget) with CIs."""
    fig, ax = curve_axes(title, scores)
    unit, xlabel = steps_axis(frames[-1])
    if by_fraction:
        unit, xlabel = 1.0, "Fraction of each task's budget (total_timesteps)"
    plot_utils.plot_sample_efficiency_curve(
        frames / unit, by_label(point, labels), by_label(interval, labels),
        colors={labels(g): colors[g] for g in point}, xlabel=xlabel, ylabel=ylabel, ax=ax,
        marker=".", **CURVE_STYLE)
    return fig


# ------------------------------------------------ the headline figure (paired differences)
@dataclasses.dataclass
class PairedCell:
    """One series' paired difference at one x of plot_paired: per seed the value (and its
    standard error, from the robust evaluation); (mean, low, high) of the bootstrap and t."""

    values: np.ndarray
    boot: Sequence[float]
    t: Sequence[float]
    errors: np.ndarray | None = None
    markers: Sequence[str] | None = None  # per value, its task's, where from several tasks
    seeds: Sequence[int] | None = None  # the seeds of `values`, for plot_per_seed


@dataclasses.dataclass
class PairedRow:
    """A panel of the headline figure: a task, or the tasks together; (x, series) -> cell."""

    title: str
    ticks: list[str]
    cells: dict[tuple[int, object], PairedCell]
    ylabel: str
    reference: tuple[float, str] | None = None  # tanh(mu)'s return: a right axis in % of it
    shapes: dict[str, str] = dataclasses.field(default_factory=dict)  # task -> its marker


def draw_seed_summary(ax, x: float, width: float, cell: PairedCell, color: tuple) -> None:
    """Within x +- width: the seeds (dots, left; whiskers: +-VERDICT_SE standard errors, where
    given), their mean (tick) with its t-interval and, right, the bootstrap CI (bar). Dots
    beyond the axis sit on its edge as triangles, the farthest one's value written."""
    values, errors, boot, t_values = cell.values, cell.errors, cell.boot, cell.t
    xs = x - 0.6 * width + np.linspace(-0.15, 0.15, values.size) * width
    low, high = ax.get_ylim()
    outside = [i for i, v in enumerate(values) if not low <= v <= high]
    farthest = max(outside, key=lambda i: abs(values[i]), default=None)
    for i, (xi, value) in enumerate(zip(xs, values, strict=True)):
        inside = i not in outside
        marker = (cell.markers[i] if cell.markers else "o") if inside else \
            ("v" if value < low else "^")
        ax.scatter(xi, min(max(value, low), high), s=16, marker=marker, color=color, alpha=0.7,
                   lw=0, zorder=3, clip_on=False)
        if i == farthest:  # inside the axes, off the spine, so that its sign stays legible
            below = value < low
            ax.annotate(f"{value:.3g}", (xi, min(max(value, low), high)),
                        xytext=(0, 4 if below else -4), textcoords="offset points",
                        ha="center", va="bottom" if below else "top", fontsize=6,
                        bbox={"fc": "white", "ec": "none", "pad": 0.3, "alpha": 0.8})
        elif inside and errors is not None and np.isfinite(errors[i]):
            ax.errorbar(xi, value, yerr=estimators.VERDICT_SE * errors[i], color=color, lw=0.7,
                        alpha=0.7, zorder=3)
    ax.bar(x + 0.6 * width, boot[2] - boot[1], bottom=boot[1], width=0.4 * width, color=color,
           alpha=0.4)
    ax.hlines(t_values[0], x - 0.35 * width, x + 0.35 * width, color="k", lw=1.5, zorder=4)
    if np.isfinite(t_values[1]):
        ax.errorbar(x, t_values[0], yerr=[[t_values[0] - t_values[1]], [t_values[2] -
                    t_values[0]]], color=color, lw=1.5, capsize=3, zorder=4)


def marker_shapes(keys: Sequence) -> dict:
    """A marker shape per key (task or seed): twelve shapes, repeated beyond, so that no count of
    tasks or seeds runs out of them (the classic suite beside the HumanoidBench tasks is nine)."""
    return dict(zip(keys, itertools.cycle("osD^vP*Xph<>")))


def summary_range(cells: Sequence[PairedCell]) -> tuple[float, float]:
    """A y-range holding the intervals, zero and the middle 90% of the dots (not an outlier)."""
    bounds = [v for c in cells for v in (*c.boot, *c.t) if np.isfinite(v)] + [0.0]
    dots = np.concatenate([c.values for c in cells])
    low = min(min(bounds), np.percentile(dots, 5))
    high = max(max(bounds), np.percentile(dots, 95))
    pad = 0.12 * (high - low or 1.0)
    return low - pad, high + pad


def series_slots(rows: Sequence[PairedRow]) -> tuple[list, float, dict]:
    """The series in order of appearance, each one's share of an x and its offset there."""
    series = list(dict.fromkeys(s for row in rows for _, s in row.cells))
    slot = 0.8 / len(series)
    return series, slot, {s: (j - (len(series) - 1) / 2) * slot for j, s in enumerate(series)}


def frame_panel(ax: plt.Axes, row: PairedRow) -> None:
    """A task panel's ticks, title, labels, zero line and a right axis in % of row.reference."""
    ax.set_xticks(range(len(row.ticks)), row.ticks, fontsize="small")
    ax.set_xlim(-0.5, len(row.ticks) - 0.5)
    ax.set_title(row.title, fontsize="medium")
    ax.set_ylabel(row.ylabel)
    if row.reference is not None:
        value, where = row.reference
        scale = abs(value) or 1.0
        right = ax.secondary_yaxis("right", functions=(lambda y, r=scale: 100 * y / r,
                                                       lambda p, r=scale: p * r / 100))
        right.set_ylabel(f"% of tanh(mu)'s return ({value:.3g} {where})", fontsize="small")
    ax.axhline(0, color="0.4", ls=":", lw=1)
    ax.grid(axis="y", alpha=0.25)


def panel_width(rows: Sequence[PairedRow]) -> float:
    """Inches: wider with more x's, so that tick labels such as "bookshelf_simple" (one per task in
    the dimension study) do not run into each other."""
    return max(8.0, 1.3 * max(len(row.ticks) for row in rows) + 1.5)


def plot_paired(rows: Sequence[PairedRow], colors: dict, labels: dict, how: str) -> plt.Figure:
    """The headline figure, the training log's and the robust evaluation's: a panel per row, in
    each every series' paired difference at each x (draw_seed_summary). `how`: the protocol."""
    series, slot, offsets = series_slots(rows)
    fig, axes = plt.subplots(len(rows), 1, figsize=(panel_width(rows), 3.1 * len(rows) + 1.0),
                             squeeze=False, layout="constrained")
    for ax, row in zip(axes[:, 0], rows, strict=True):
        ax.set_ylim(*summary_range(list(row.cells.values())))
        for (i, s), cell in row.cells.items():
            draw_seed_summary(ax, i + offsets[s], slot / 2, cell, colors[s])
        frame_panel(ax, row)
        if row.shapes:
            ax.legend(handles=[plt.Line2D([], [], ls="", marker=m, color="0.4", label=t)
                               for t, m in row.shapes.items()], fontsize="x-small", loc="best")
    handles = [Patch(color=colors[s], label=labels[s]) for s in series]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 3),
               fontsize="small", title="evaluation action", title_fontsize="small")
    episodes = any(c.errors is not None for row in rows for c in row.cells.values())
    dots = f"dots: seeds, +-{estimators.VERDICT_SE:g} SE of their paired episodes" if episodes \
        else "dots: seeds"
    fig.suptitle(f"Each action minus tanh(mu): same actor, same start states\n{how}\n{dots} "
                 "(triangles: beyond the axis)\ntick and whisker: mean over seeds and its 95% "
                 "t-interval; bar: bootstrap CI", fontsize="medium")
    return fig


def plot_per_seed(rows: Sequence[PairedRow], colors: dict, labels: dict, how: str
                  ) -> plt.Figure:
    """The robust evaluation's verdicts: plot_paired's task panels with only the seeds, +-
    VERDICT_SE standard errors each, on an axis scaled to them (the mean's t-interval would
    hide them); filled where estimators.verdict says ahead or behind, hollow where level."""
    series, slot, offsets = series_slots(rows)
    every = sorted({int(seed) for row in rows for c in row.cells.values() for seed in c.seeds})
    shapes = marker_shapes(every)
    fig, axes = plt.subplots(len(rows), 1, figsize=(panel_width(rows), 2.8 * len(rows) + 1.2),
                             squeeze=False, layout="constrained")
    for ax, row in zip(axes[:, 0], rows, strict=True):
        seeds = sorted({int(seed) for c in row.cells.values() for seed in c.seeds})
        spread = np.linspace(-0.35, 0.35, len(seeds)) * slot if len(seeds) > 1 else [0.0]
        for (i, s), cell in row.cells.items():
            for seed, value, error in zip(cell.seeds, cell.values, cell.errors, strict=True):
                x = i + offsets[s] + spread[seeds.index(int(seed))]
                decided = estimators.verdict(value, error) in ("ahead", "behind")
                whisker = None if np.isnan(error) else estimators.VERDICT_SE * error
                ax.errorbar(x, value, yerr=whisker,
                            color=colors[s], lw=0.8, zorder=3, ls="", marker=shapes[int(seed)],
                            ms=4.5, mfc=colors[s] if decided else "white", mec=colors[s])
        frame_panel(ax, row)
    handles = [Patch(color=colors[s], label=labels[s]) for s in series]
    handles += [plt.Line2D([], [], ls="", marker=m, color="0.4", label=f"seed {seed}")
                for seed, m in shapes.items()]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 4),
               fontsize="small", title="evaluation action; seed", title_fontsize="small")
    fig.suptitle(f"Each seed's action minus tanh(mu): same actor, same start states\n{how}\n"
                 f"whisker: +-{estimators.VERDICT_SE:g} SE of the seed's paired episodes; filled: "
                 "beyond it (ahead or behind), hollow: level", fontsize="medium")
    return fig


# The over-training figure's rolling mean, over this many rounds (drawn with twice as many).
ROLLING_ROUNDS = 10


def mark_restarts(ax: plt.Axes, marks: Sequence[tuple[int, int]], unit: float,
                  named: bool = True) -> None:
    """A dashed line where a run restarted from a snapshot: past it the curve is a new sample,
    not the lost run's future. `named`: the seeds beside each line, and a legend entry."""
    seeds_at: dict[int, list[int]] = {}  # runs restarted at one step share a line and a label
    for seed, step in marks:
        seeds_at.setdefault(step, []).append(seed)
    for i, (step, seeds) in enumerate(sorted(seeds_at.items())):
        ax.axvline(step / unit, color="0.25", ls="--", lw=0.9,
                   label="a run restarted from a snapshot" if named and i == 0 else None)
        if named:
            words = f"seed{'s' * (len(seeds) > 1)} {', '.join(map(str, sorted(seeds)))}"
            ax.text(step / unit, 0.98, f"{words} ", rotation=90, ha="right", va="top",
                    fontsize="x-small", color="0.25", transform=ax.get_xaxis_transform())


def plot_over_training(steps: dict[str, np.ndarray], differences: dict, estimates: dict,
                       shifts: dict, shift_columns: Sequence[str], colors: dict, names: dict,
                       restarts: dict[str, list[tuple[int, int]]] | None = None) -> plt.Figure:
    """A row per task. Left: each evaluation action minus tanh(mu) over training; with many
    rounds each round's mean over seeds (thin) and its rolling mean (thick), with few the mean,
    its CI and each seed. Right: the `shift_columns` (mean over the corrected runs, band: their
    range); `restarts`: task -> (seed, step), marked on every panel."""
    shown = [t for t in steps if t in differences or t in shifts]
    titles = ("|mode - tanh(mu)|\nmean over dimensions", "sigma\nmean over dimensions",
              "two-mode share: dimensions\nwith 2 sigma^2 > 1")
    fig, axes = plt.subplots(len(shown), 4, figsize=(15.0, 3.4 * len(shown) + 0.6),
                             squeeze=False, gridspec_kw={"width_ratios": (2.3, 1, 1, 1)},
                             layout="constrained")
    for row, task in zip(axes, shown, strict=True):
        unit, xlabel = steps_axis(steps[task][-1])
        x = steps[task] / unit
        ax = row[0]
        rolling = x.size >= 2 * ROLLING_ROUNDS
        seeds = set()
        for group, diffs in differences.get(task, {}).items():
            mean, (low, high) = estimates[task][group]
            seeds.add(diffs.shape[0])
            name = names[group]
            if rolling:  # a round is one draw of the evaluation noise: the trend needs a window
                ax.plot(x, mean, color=colors[group], lw=0.7, alpha=0.45)
                window = np.convolve(mean, np.ones(ROLLING_ROUNDS) / ROLLING_ROUNDS, "valid")
                ax.plot(x[ROLLING_ROUNDS - 1:], window, color=colors[group], lw=2.2,
                        label=name)
            else:
                ax.plot(x, mean, "o-", color=colors[group], lw=1.8, ms=4, label=name)
                ax.fill_between(x, low, high, color=colors[group], alpha=0.2, lw=0)
                ax.plot(x, diffs.T, color=colors[group], lw=0.5, alpha=0.35)
        ax.axhline(0, color="0.4", ls=":", lw=1)
        marks = (restarts or {}).get(task, [])
        mark_restarts(ax, marks, unit)
        n = " or ".join(map(str, sorted(seeds)))
        how = (f"thin: each round's mean over seeds; thick: mean of the last {ROLLING_ROUNDS} "
               "rounds" if rolling else "mean over seeds, 95% bootstrap CI; thin: each seed"
               + ("\n(from this few seeds the CI is narrower than the data allow)"
                  if seeds and min(seeds) <= estimators.FEW_SEEDS else ""))
        ax.set_title(f"{task}, n = {counted(n, 'seed')}\n{how}", fontsize="medium")
        ax.set_ylabel("Return minus tanh(mu)'s")
        ax.legend(fontsize="small", frameon=False, loc="upper center", ncols=3,
                  bbox_to_anchor=(0.5, -0.16))  # under the axes: clear of the restart marks
        for ax, column, title in zip(row[1:], shift_columns, titles, strict=True):
            values = shifts.get(task, {}).get(column)
            if values is None:
                ax.text(0.5, 0.5, "not logged", ha="center", va="center",
                        transform=ax.transAxes, color="0.4")
            else:
                ax.plot(x, values.mean(0), color="k", lw=1.4)
                ax.fill_between(x, values.min(0), values.max(0), color="0.5", alpha=0.25, lw=0)
                if column != "bimodal_fraction" and np.all(values > 0):
                    ax.set_yscale("log")  # the first rounds' spike would flatten the rest
            mark_restarts(ax, marks, unit, named=False)
            ax.set_title(title, fontsize="medium")
        row[3].set_ylim(-0.02, 1.02)  # a share
        for ax in row:
            ax.set_xlabel(xlabel)
            ax.grid(alpha=0.25)
    fig.suptitle("Over training: each evaluation action minus tanh(mu) of the same actors, and "
                 "the distribution shift (mean over the corrected runs; band: their range)")
    return fig


SUCCESS_BAR_DRAWN_WITHIN = 1.5


def success_bar_drawn(bar: float, top: float) -> bool:
    """Whether a task's success bar is drawn on its reward curves: only within
    SUCCESS_BAR_DRAWN_WITHIN of the returns' top, which a higher bar would squash into the
    floor; otherwise the title names it."""
    return top > 0 and bar <= SUCCESS_BAR_DRAWN_WITHIN * top


def plot_reward_curves(steps: dict[str, np.ndarray], curves: dict, colors: dict,
                       labels: Callable, styles: dict, bars: dict[str, float], heading: str,
                       restarts: dict[str, list[tuple[int, int]]] | None = None) -> plt.Figure:
    """Figure 5: per task, each group's mean evaluation return with its interval, `curves`: task
    -> group -> (mean, (low, high)), in legend order; `styles`: (task, group) -> line style;
    `bars`: success bars; `restarts` as plot_over_training's."""
    ncols = math.ceil(math.sqrt(len(steps)))
    nrows = math.ceil(len(steps) / ncols)
    # At least 9 inches wide, so that the legend below fits in a few rows beside one panel.
    width = max(5.6 * ncols, 9.0)
    fig, axes = plt.subplots(nrows, ncols, figsize=(width, 4.0 * nrows + 0.9), squeeze=False)
    for ax in axes.flat[len(steps) :]:
        ax.set_visible(False)
    for ax, (task, x) in zip(axes.flat, steps.items(), strict=False):
        unit, xlabel = steps_axis(x[-1])
        width_line = 1.8 if x.size <= 200 else 1.0  # dense curves: thin lines show CIs
        top = -math.inf
        for group, (mean, (low, high)) in curves[task].items():
            style = styles[task, group]
            ax.plot(x / unit, mean, style, color=colors[group], lw=width_line,
                    label=labels(group) + (" (one episode per evaluation)" if style == ":"
                                           else ""))
            ax.fill_between(x / unit, low, high, color=colors[group], alpha=0.2, lw=0)
            top = max(top, float(np.max(high)))
        mark_restarts(ax, (restarts or {}).get(task, []), unit)
        title = task
        if task in bars:
            bar = bars[task]
            if success_bar_drawn(bar, top):
                ax.axhline(bar, color="0.4", ls=":", lw=1.2, label="success bar")
            else:
                title += f"\nsuccess bar {bar:g} (above)"
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("Evaluation return")
        ax.grid(alpha=0.25)
    handles = {label: handle for ax in axes.flat
               for handle, label in zip(*ax.get_legend_handles_labels(), strict=True)}
    ncol = max(1, min(len(handles), int(width // 3.0)))
    fig.legend(handles.values(), handles.keys(), loc="lower center", ncol=ncol,
               frameon=False)
    legend_rows = math.ceil(len(handles) / ncol)
    fig.suptitle(heading)
    fig.tight_layout(rect=(0, (0.27 * legend_rows + 0.05) / fig.get_figheight(), 1, 1))
    return fig


def plot_probability_of_improvement(probability: float, ci: np.ndarray, x: object, y: object,
                                    color: tuple, labels: Callable) -> plt.Figure:
    """P(a run of x beats a run of y) on a random task (rliable's plot)."""
    fig, ax = plt.subplots(figsize=(6, 1.4))
    pair = f"{labels(x)};{labels(y)}"
    plot_utils.plot_probability_of_improvement(
        {pair: probability}, {pair: ci}, pair_separator=";", ax=ax, colors=[color],
        xticks=[0, 0.25, 0.5, 0.75, 1.0], xlabel=f"P({labels(x)} > {labels(y)})",
        ticklabelsize="large", labelsize="large", left_ylabel="", right_ylabel="",
    )
    ax.set_xlim(0, 1)
    ax.axvline(0.5, color="0.5", ls=":", lw=1)
    ax.text(0.5, -0.72, "every run of one against every run of the other: it ignores the pairing "
            "(paired_difference.png has it)", transform=ax.transAxes, ha="center", va="top",
            fontsize="medium", color="0.3")
    return fig


# ------------------------------------------------------------------ the dimension study
def dimension_positions(study: dict[str, Dimension]) -> dict[str, float]:
    """Each task's x on the log dimension axis: its action dimension, tasks sharing one spread
    a little so that their CIs do not hide each other."""
    positions = {}
    for dim in {d.action_dim for d in study.values()}:
        same = [t for t, d in study.items() if d.action_dim == dim]
        for k, task in enumerate(same):
            positions[task] = dim * 1.07 ** (k - (len(same) - 1) / 2)
    return positions


def _errorbar(ax, x: float, estimate: tuple[float, float, float], **style) -> None:
    point, low, high = estimate
    ax.errorbar(x, point, yerr=[[point - low], [high - point]], capsize=3, **style)


def plot_dimension_study(study: dict[str, Dimension], estimates: dict, colors: list,
                         labels, order: Sequence[str]) -> plt.Figure:
    """Per evaluation action (in `order`, then any other), a row: its paired difference against
    the action dimension and against training; last row: the measured shift beside
    mode_search's theory, and sigma / bimodal share against the dimension."""
    from mode_search import SPREADS, summed_shift_by_dimension  # torch: only for this figure

    found = {g[1] for d in study.values() for g in d.differences}
    actions = [a for a in order if a in found] + sorted(found - set(order))
    fig, axes = plt.subplots(len(actions) + 1, 2, figsize=(13, 4.75 * (len(actions) + 1)),
                             squeeze=False, layout="constrained")  # constrained: room for suptitle
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
    return fig


def _plot_difference(ax_dim, ax_progress, x: float, d: Dimension, estimates: dict,
                     key: tuple[str, str], color, marker: str, label: str) -> None:
    """One (task, evaluation action): against the dimension and against training."""
    fractions = sorted(d.steps)
    _errorbar(ax_dim, x, estimates[key, 1.0], fmt=marker, color=color, ms=7, label=label)
    for f in fractions[:-1]:  # earlier in training: hollow, fainter the earlier
        ax_dim.plot(x, estimates[key, f][0], marker, mfc="none", color=color,
                    alpha=0.25 + 0.6 * f, ms=4 + 3 * f)
    ax_progress.plot(fractions, [estimates[key, f][0] for f in fractions], f"{marker}-",
                     color=color, label=label)
    ax_progress.fill_between(fractions, [estimates[key, f][1] for f in fractions],
                             [estimates[key, f][2] for f in fractions], color=color, alpha=0.15)
