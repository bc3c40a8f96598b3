"""What analyze.py's reports are made of: summary.csv rows, summary.md sections and tables,
figures' files and notes, and the cells they print."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from analysis import estimators


def interval_text(point: float, low: float, high: float, digits: int = 3, runs: int = 2
                  ) -> str:
    """"0.123 [0.100, 0.150]"; "0.123 (n/a)" where there is no interval: NaN bounds, or an
    estimate from one run, whose bootstrap resamples that run alone."""
    if runs < 2 or math.isnan(low) or math.isnan(high):
        return f"{point:.{digits}f} (n/a)"
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def counted(n: int | str, noun: str) -> str:
    """'1 seed', '3 seeds', '2 or 3 seeds'."""
    return f"{n} {noun}" + ("" if str(n) == "1" else "s")


def format_step(step: int | float) -> str:
    """Steps as people write them: 10M, 2.5M, 250k, 1,234."""
    step = int(step)
    if step >= 1_000_000 and step % 1_000 == 0:
        return f"{step / 1_000_000:g}M"
    if step >= 1_000 and step % 1_000 == 0:
        return f"{step // 1_000}k"
    return f"{step:,}"


def seed_cells(values: np.ndarray, estimate: Sequence[float], digits: int = 3
               ) -> tuple[str, str]:
    """summary.md's cells for the mean of one value per seed: (mean with its bootstrap CI,
    t-interval). Two seeds' bootstrap CI says less than the two values, so the first cell gives
    those ("two seeds: a to b"). One seed has neither."""
    point = estimate[0]
    if values.size == 1:
        return f"{point:.{digits}f} (one seed)", "-"
    _, low, high = estimators.t_interval(values)
    t_cell = f"[{low:.{digits}f}, {high:.{digits}f}]"
    if values.size == 2:
        a, b = sorted(float(v) for v in values)
        return f"{point:.{digits}f} (two seeds: {a:.{digits}f} to {b:.{digits}f})", t_cell
    return interval_text(*estimate, digits=digits), t_cell


def share_above_zero(values: np.ndarray) -> float:
    """summary.csv's share of the values above zero: a count of signs that decides nothing (the
    verdicts are estimators.verdict's and the t-interval's)."""
    return int((values > 0).sum()) / values.size


def above_zero(values: np.ndarray) -> str:
    """summary.md's 'above zero' cell, "k of n"."""
    return f"{int((values > 0).sum())} of {values.size}"


def save_palette_png(image: Image.Image, path: Path,
                     method: Image.Quantize = Image.Quantize.MEDIANCUT) -> None:
    """A 256-colour PNG, about 40% of the RGB file with no difference to see (git keeps every
    version a campaign commits). Median cut keeps the plots' faint grid lines; octree, the
    renders' small saturated objects."""
    image.convert("RGB").quantize(256, method=method, dither=Image.Dither.NONE).save(
        path, optimize=True)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(map(str, row)) + " |" for row in rows])


@dataclasses.dataclass
class Report:
    """What an analysis writes: summary.csv rows, summary.md sections, figures, notes. A row's
    group is a name, or a key that `names` turns into one."""

    out: Path
    formats: Sequence[str]
    notes: list[str] = dataclasses.field(default_factory=list)
    names: Callable[[object], str] = str
    rows: list[dict] = dataclasses.field(default_factory=list)
    sections: list[str] = dataclasses.field(default_factory=list)
    figures: list[Path] = dataclasses.field(default_factory=list)

    def row(self, section: str, task: str, group: object, metric: str, step: int | str,
            runs: int | str, estimate: float, low: float, high: float) -> None:
        name = group if isinstance(group, str) else self.names(group)
        self.rows.append(dict(section=section, task=task, group=name, metric=metric, step=step,
                              n_runs=runs, estimate=float(estimate), ci_low=float(low),
                              ci_high=float(high)))

    def figure(self, fig: plt.Figure, name: str) -> None:
        for fmt in self.formats:
            self.figures.append(self.out / f"{name}.{fmt}")
            if fmt != "png":
                fig.savefig(self.figures[-1], dpi=150, bbox_inches="tight")
                continue
            buffer = io.BytesIO()
            fig.savefig(buffer, format="png", dpi=150, bbox_inches="tight")
            save_palette_png(Image.open(buffer), self.figures[-1])
        plt.close(fig)

    def section(self, title: str, *lines: str) -> None:
        self.sections += [f"## {title}", "", *lines, ""]

    def write(self, header: list[str]) -> None:
        with (self.out / "summary.csv").open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(self.rows[0]))
            writer.writeheader()
            writer.writerows(self.rows)
        notes = ["## Notes", "", *([f"- {note}" for note in self.notes] or ["- none"]), ""]
        figures = ["## Figures", "", *[f"- `{path.name}`" for path in self.figures]]
        text = "\n".join(header + notes + self.sections + figures) + "\n"
        (self.out / "summary.md").write_text(text)
        print("\n".join(["", *notes, *self.sections]))
        print(f"wrote {len(self.figures) + 2} files to {self.out}")


# ---------------------------------------- the per-seed tables: evaluate.py's and analyze.py's
END_PREFIX = "end_"  # per_seed.csv's end_<why>: the episodes that ended so
PAIRED_ENDS = ("fell", "terminated", "time_limit")  # the paired table's, for its first action
# Ends whose paired share evaluate.py tests as the returns are (per_seed.csv's
# <why>_difference_mean and _se): the h1hand robot down, and gymnasium's termination (Hopper,
# Walker2d, Ant and Humanoid end early only when the body leaves its healthy range).
SHARE_ENDS = ("fell", "terminated")


def se_distance(mean: float, se: float) -> str:
    """Standard errors from zero, with a third digit within 0.1 of the verdict's line."""
    z = abs(mean) / se if se > 0 else (math.inf if mean else 0.0)
    return f"{z:#.3g}" if abs(z - estimators.VERDICT_SE) < 0.1 else f"{z:#.2g}".rstrip(".")


def paired_cell(mean: float, se: float, digits: int,
                judge: Callable[[float, float], str] = estimators.verdict) -> tuple[str, str]:
    """("+1.2 +- 0.3", "**ahead**, 4.0 SE"): a paired difference and its verdict."""
    word = judge(mean, se)
    return (f"{mean:+.{digits}f} +- {se:.{digits}f}",
            f"{word if word in ('level', 'n/a') else f'**{word}**'}, {se_distance(mean, se)} SE")


def _given(row: Mapping[str, object] | None, column: str) -> object | None:
    """A cell of per_seed.csv, None where it is missing or empty (not recorded)."""
    value = None if row is None else row.get(column)
    return None if value is None or value == "" or (
        isinstance(value, float) and math.isnan(value)) else value


def _count(row: Mapping[str, object] | None, column: str) -> str:
    value = _given(row, column)
    return "n/r" if value is None else str(int(value))


def _share(row: Mapping[str, object] | None, why: str) -> str:
    """The paired difference in the share of episodes that ended `why` (a SHARE_ENDS) and its
    verdict; "" where not recorded."""
    if _given(row, f"{why}_difference_se") is None:
        return ""
    return "{}: {}".format(*paired_cell(row[f"{why}_difference_mean"],
                                        row[f"{why}_difference_se"], 2, estimators.fall_verdict))


def per_seed_tables(rows: Sequence[Mapping[str, object]], actions: Sequence[str]) -> list[str]:
    """summary.md's per-seed tables, evaluate.py's and analyze.py's (--robust), from per_seed.csv's
    rows. Per task, a row per policy: tanh(mu)'s return and each action minus tanh(mu), with the
    verdict, and the first action's falls and time limits against tanh(mu)'s where recorded;
    then a row per policy and action: how its episodes ended."""
    baseline, compared = estimators.BASELINE, [a for a in actions if a != estimators.BASELINE]
    by_task: dict[str, dict[tuple[int, int], dict[str, Mapping]]] = {}
    for row in rows:
        by_task.setdefault(str(row["env_id"]), {}).setdefault(
            (int(row["seed"]), int(row["step"])), {})[str(row["selector"])] = row
    falls = any(_given(r, END_PREFIX + "fell") is not None for r in rows)
    terminations = any(_given(r, END_PREFIX + "terminated") is not None for r in rows)
    lines = [f"Per policy: tanh(mu)'s mean return +- its standard error; each action minus "
             f"tanh(mu) from the same starts +- the standard error of the paired episodes, ahead "
             f"/ behind where more than {estimators.VERDICT_SE:g} standard errors from zero, else "
             "level, and how many from zero" + ("; fell: its episodes and tanh(mu)'s that ended "
             "with the robot down, and the paired difference of the two shares (per start, 1 "
             "where its episode fell minus 1 where tanh(mu)'s did), more / fewer by the same "
             "rule" if falls else "") + ("; terminated: its episodes and tanh(mu)'s that the "
             "task ended early (gymnasium's locomotion tasks: the body left its healthy range), "
             "and the paired difference of the two shares, more / fewer by the same rule"
             if terminations else "") + "; n/r: not recorded.", ""]
    for task, policies in by_task.items():
        recorded = [r for p in policies.values() for r in p.values()]
        reasons = sorted({c.removeprefix(END_PREFIX) for r in recorded for c in r
                          if c.startswith(END_PREFIX) and _given(r, c)})  # some episode did
        unstable = any(_given(r, "unstable_ends") is not None for r in recorded)
        shown = [a for a in compared if any(a in p for p in policies.values())]
        ends = [why for why in PAIRED_ENDS if why in reasons and shown]
        header = ["seed", "step", "tanh(mu)'s return", *(f"{a} - tanh(mu)" for a in shown),
                  *(f"{why.replace('_', ' ')} ({shown[0]} / tanh(mu))" for why in ends)]
        table, ended = [], []
        for (seed, step), by in sorted(policies.items()):
            base = by.get(baseline)
            cells = [str(seed), format_step(step), "-" if _given(base, "return_se") is None else
                     f"{base['return_mean']:.1f} +- {base['return_se']:.1f}"]
            for action in shown:
                it = by.get(action)
                cells.append("-" if _given(it, "difference_se") is None else "{} ({})".format(
                    *paired_cell(it["difference_mean"], it["difference_se"], 1)))
            for why in ends:
                it, column = by.get(shown[0]), END_PREFIX + why
                share = _share(it, why) if why in SHARE_ENDS else ""
                cells.append(f"{_count(it, column)} / {_count(base, column)}"
                             + (f" ({share})" if share else ""))
            table.append(cells)
            for action in (a for a in actions if a in by):
                it = by[action]
                ended.append([str(seed), format_step(step), action,
                              *(_count(it, END_PREFIX + why) for why in reasons),
                              *(_share(it, why) for why in SHARE_ENDS if why in reasons),
                              *([_count(it, "unstable_ends")] if unstable else [])])
        lines += [f"{task}:", "", markdown_table(header, table), ""]
        if reasons or unstable:
            lines += [f"{task}, how each action's episodes ended (per policy; blow-ups: the "
                      "episodes a physics blow-up ended):", "", markdown_table(
                          ["seed", "step", "action", *(r.replace("_", " ") for r in reasons),
                           *(f"{why}, minus tanh(mu)" for why in SHARE_ENDS if why in reasons),
                           *(["blow-ups"] if unstable else [])], ended), ""]
    return lines
