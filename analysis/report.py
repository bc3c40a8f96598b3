"""What analyze.py's reports are made of: summary.csv rows, summary.md sections and tables,
figures and notes, and the cells and numbers they print (steps, intervals, seeds)."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Callable, Sequence
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
    t-interval). Two seeds' bootstrap CI says less than the values themselves, so the first
    cell gives those ("two seeds: a to b"); their t-interval (one degree of freedom) stays,
    since the rule that decides a task reads it. One seed has neither."""
    point = estimate[0]
    if values.size == 1:
        return f"{point:.{digits}f} (one seed)", "-"
    _, low, high = estimators.t_interval(values)
    t_cell = f"[{low:.{digits}f}, {high:.{digits}f}]"
    if values.size == 2:
        a, b = sorted(float(v) for v in values)
        return f"{point:.{digits}f} (two seeds: {a:.{digits}f} to {b:.{digits}f})", t_cell
    return interval_text(*estimate, digits=digits), t_cell


def positives(values: np.ndarray) -> int:
    """How many of the values are above zero: a count of signs that decides nothing (the
    verdicts are estimators.verdict's and the t-interval's)."""
    return int((values > 0).sum())


def share_above_zero(values: np.ndarray) -> float:
    """summary.csv's share_above_zero: the fraction of the values above zero."""
    return positives(values) / values.size


def above_zero(values: np.ndarray) -> str:
    """summary.md's 'above zero' cell, "k of n"."""
    return f"{positives(values)} of {values.size}"


def save_palette_png(image: Image.Image, path: Path,
                     method: Image.Quantize = Image.Quantize.MEDIANCUT) -> None:
    """A 256-colour PNG: plots have few distinct colours, so it is about 40% of the RGB file with
    no difference to see (git keeps every version a campaign commits). Median cut keeps the
    plots' faint grid lines; octree, the renders' small saturated objects."""
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
