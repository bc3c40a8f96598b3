"""Regenerate the README's pictures in docs/ with the project's own code:

    MUJOCO_GL=egl .venv/bin/python docs/make_figures.py            # all three, ~4 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python docs/make_figures.py tasks mode # skip the training runs
    .venv/bin/python docs/make_figures.py theory --out DIR         # the theory figures, to DIR

- tasks: `python -m humanoid_envs.render`, every h1hand task's start state (h1hand_tasks.png);
- mode: the action-bias figure, the mode of tanh(u) against tanh(mu) (mode_vs_tanh_mu.png);
- theory (not part of the default; to --out): from mode_search.py's mathematics, the paper's
  Figs. 1-4, the summed shift against the number of dimensions and the mode / median / mean
  against sigma;
- analysis: three tiny sac_corrected.py runs on Pendulum-v1 (seeds 0-2, 8,000 steps), then
  analyze.py over them; its reward-curve figure (analyze_reward_curves.png). Illustrative of
  the report's layout, not a result.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import torch
from PIL import Image

# Offscreen rendering without a display, as the tests render; read when mujoco is imported.
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # the scripts' modules import from the repository root

from analysis.report import save_palette_png as palette_png  # noqa: E402
from mode_search import (  # noqa: E402
    SPREADS,
    mean_action,
    mode_action,
    summed_shift_by_dimension,
    tanh_normal_log_prob,
)

# Pendulum-v1 learns in a few thousand steps on a CPU; short enough to keep the docs cheap.
TINY_RUN = [
    "--env-id", "Pendulum-v1", "--total-timesteps", "8000", "--learning-starts", "1000",
    "--eval-interval", "500", "--eval-episodes", "5", "--checkpoint-interval", "0",
    "--no-cuda", "--print-interval", "4000",
]  # fmt: skip
SEEDS = (0, 1, 2)


def save_palette_png(image: Image.Image, path: Path) -> None:
    palette_png(image, path, Image.Quantize.FASTOCTREE)
    print(f"wrote {path.relative_to(ROOT)} ({path.stat().st_size / 1024:.0f} KB)")


# --- the theory figures (mode_search.py's mathematics): the paper's Figs. 1-4 and two of ours
def write_theory_figures(out_dir: Path) -> list[Path]:
    """Write the paper's theory figures (Figs. 1-4), the shift-vs-dimension figure and the
    mode / median / mean against sigma as PNGs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    plots = [
        _plot_motivation,
        _plot_distribution_shift,
        _plot_action_bias,
        _plot_2d_example,
        _plot_shift_vs_dimensions,
        _plot_mode_median_mean,
    ]
    paths = []
    for plot in plots:
        fig, name = plot(plt)
        paths.append(out_dir / f"{name}.png")
        fig.savefig(paths[-1], dpi=150, bbox_inches="tight")
        plt.close(fig)
    return paths


def _gaussian_pdf(u: torch.Tensor, mu: float, sigma: float) -> torch.Tensor:
    return torch.exp(-0.5 * ((u - mu) / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))


def _tanh_normal_pdf(y: torch.Tensor, mu: float, sigma: float) -> torch.Tensor:
    return tanh_normal_log_prob(y, torch.tensor(mu), torch.tensor(math.log(sigma))).exp()


def _plot_gaussian_and_squashed(ax, mu: float, sigma: float, label: bool) -> None:
    """Gaussian density of u (blue dashed) and of y = tanh(u) on its domain (red solid)."""
    u = torch.linspace(-2.5, 2.5, 2001, dtype=torch.float64)
    y = torch.linspace(-1, 1, 4001, dtype=torch.float64)[1:-1]
    gaussian_label = f"Gaussian density of u ~ N($\\mu$, {sigma:g}$^2$)" if label else None
    ax.plot(u, _gaussian_pdf(u, mu, sigma), "b--", label=gaussian_label)
    ax.plot(
        y, _tanh_normal_pdf(y, mu, sigma), "r-", label="density of y = tanh(u)" if label else None
    )


def _style_density_axes(ax, title: str) -> None:
    ax.axvspan(-2.5, -1, color="0.93", zorder=0)
    ax.axvspan(1, 2.5, color="0.93", zorder=0, label="outside the action range")
    ax.set(xlabel="u (Gaussian) / y (transformed)", ylabel="density", xlim=(-2.5, 2.5))
    ax.set(ylim=(0, None), title=title)


def _plot_motivation(plt):
    fig, ax = plt.subplots(figsize=(7, 4))
    _plot_gaussian_and_squashed(ax, mu=0.5, sigma=0.6, label=True)
    _style_density_axes(ax, "A Gaussian and its tanh transform: $\\mu$ = 0.5, $\\sigma$ = 0.6")
    ax.legend(loc="upper left", fontsize=8)
    return fig, "fig1_gaussian_vs_tanh"


def _plot_distribution_shift(plt):
    fig, ax = plt.subplots(figsize=(7, 4))
    for mu in (1.0, 0.0, -1.0):
        _plot_gaussian_and_squashed(ax, mu, sigma=0.5, label=mu == 1.0)
        peak = mode_action(torch.tensor(mu), torch.tensor(math.log(0.5)))
        height = _tanh_normal_pdf(peak, mu, 0.5)
        ax.annotate(
            f"$\\mu$ = {mu:g}",
            (peak, height),
            xytext=(0, 5),
            textcoords="offset points",
            ha="center",
        )
    _style_density_axes(ax, "The tanh transform of N($\\mu$, 0.5$^2$) for $\\mu$ = 1, 0, -1")
    ax.set_ylim(0, 3.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, fontsize=8)
    return fig, "fig2_distribution_shift"


def _plot_action_bias(plt):
    sigma = 0.5
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for mu in (1.0, -1.0):
        first = mu == 1.0
        _plot_gaussian_and_squashed(ax, mu, sigma, label=first)
        mode = mode_action(torch.tensor(mu), torch.tensor(math.log(sigma))).item()
        tanh_mu = math.tanh(mu)
        points = [
            (mu, _gaussian_pdf(torch.tensor(mu), mu, sigma), "tab:blue", "Gaussian mode $\\mu$"),
            (
                mode,
                _tanh_normal_pdf(torch.tensor(mode), mu, sigma),
                "red",
                "mode of y (Corrected SAC)",
            ),
            (
                tanh_mu,
                _tanh_normal_pdf(torch.tensor(tanh_mu), mu, sigma),
                "orange",
                "tanh($\\mu$) (Standard SAC)",
            ),
        ]
        # Each value where no curve passes: the Gaussian's mode below and outward, the mode of y
        # outward of its peak, tanh(mu) inward, where y's density has already fallen.
        offsets = ((10, -14), (9, -3), (-9, -3))
        for (x, p, color, label), (dx, dy) in zip(points, offsets, strict=True):
            ax.plot(x, p, "o", color=color, ms=8, mec="k", zorder=3, label=label if first else None)
            side = (1 if x > 0 else -1) * (1 if dx > 0 else -1)
            ax.annotate(
                f"{x:.3f}",
                (x, p),
                xytext=(abs(dx) * side, dy),
                textcoords="offset points",
                ha="left" if side > 0 else "right",
                va="center",
                fontsize=8,
                color=color,
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.85),
                zorder=4,
            )
    _style_density_axes(ax, "Action bias at $\\mu$ = $\\pm$1, $\\sigma$ = 0.5")
    ax.set_ylim(0, 3.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, fontsize=8)
    return fig, "fig3_action_bias"


def _plot_2d_example(plt):
    mu = torch.tensor([0.6, -0.9], dtype=torch.float64)
    log_std = torch.log(torch.tensor([0.6, 0.5], dtype=torch.float64))
    axis = torch.linspace(-1, 1, 401, dtype=torch.float64)[1:-1]
    log_p = [tanh_normal_log_prob(axis, mu[i], log_std[i]) for i in range(2)]
    density = (log_p[1][:, None] + log_p[0][None, :]).exp()  # rows: y2, columns: y1
    mode, tanh_mu = mode_action(mu, log_std), torch.tanh(mu)
    fig, ax = plt.subplots(figsize=(5.6, 4.8))
    image = ax.pcolormesh(axis, axis, density, shading="auto", cmap="viridis")
    fig.colorbar(image, ax=ax, label="density p(y$_1$) p(y$_2$)")
    ax.plot(
        *tanh_mu,
        "o",
        color="orange",
        ms=9,
        mec="k",
        label=f"tanh($\\mu$) = ({tanh_mu[0]:.2f}, {tanh_mu[1]:.2f})",
    )
    ax.plot(*mode, "*", color="red", ms=14, mec="k", label=f"mode = ({mode[0]:.2f}, {mode[1]:.2f})")
    ax.set_xticks([-1, -0.5, 0, 0.5, 1])
    ax.set(
        xlabel="y$_1$",
        ylabel="y$_2$",
        xlim=(-1, 1),
        ylim=(-1, 1),
        aspect="equal",
        title="2-D action: $\\mu$ = (0.6, -0.9), $\\sigma$ = (0.6, 0.5)",
    )
    ax.legend(loc="upper right", fontsize=8)
    return fig, "fig4_2d_example"


def _plot_shift_vs_dimensions(plt):
    dims, draws = 61, 1000
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, ((label, spread), color) in enumerate(
        zip(SPREADS.items(), ("tab:red", "tab:purple"), strict=True)
    ):
        mean, low, high = summed_shift_by_dimension(dims, spread, draws, seed=i)
        n = torch.arange(1, dims + 1)
        ax.plot(n, mean, color=color, label=f"{label}: mean")
        ax.fill_between(n, low, high, color=color, alpha=0.2, label="  5-95% of draws")
        ax.annotate(
            f"{mean[-1]:.1f}",
            (dims, mean[-1]),
            xytext=(4, 0),
            textcoords="offset points",
            va="center",
            color=color,
        )
    ax.set(
        xlabel="number of action dimensions",
        ylabel="$\\sum_i$ |mode$_i$ - tanh($\\mu_i$)|",
        xlim=(1, dims),
        ylim=(0, None),
        title=f"Distance of the mode from tanh($\\mu$), $\\mu$ ~ N(0, 1), {draws} draws",
    )
    ax.legend(fontsize=8)
    return fig, "fig5_shift_vs_dimensions"


def _plot_mode_median_mean(plt):
    sigma = torch.logspace(-2, 1, 400, dtype=torch.float64)
    fig, ax = plt.subplots(figsize=(8.5, 4.5))
    # One legend entry per statistic, in grey; the colours then name mu.
    ax.plot([], [], "-", color="0.4", label="mode (Corrected SAC)")
    ax.plot([], [], ":", color="0.4", label="median = tanh($\\mu$) (Standard SAC)")
    ax.plot([], [], "--", color="0.4", label="mean E[tanh(u)]")
    colors = ("tab:blue", "tab:green", "tab:orange", "tab:red")
    for mu, color in zip((0.25, 0.5, 1.0, 2.0), colors, strict=True):
        mu_t = torch.full_like(sigma, mu)
        ax.plot(sigma, mode_action(mu_t, sigma.log()), "-", color=color, label=f"$\\mu$ = {mu:g}")
        ax.plot(sigma, torch.tanh(mu_t), ":", color=color)
        ax.plot(sigma, mean_action(mu_t, sigma.log()), "--", color=color)
    ax.set_xscale("log")
    ax.set(
        xlabel="$\\sigma$",
        ylabel="action y",
        xlim=(1e-2, 10),
        ylim=(0, 1.02),
        title="Mode, median and mean of y = tanh(u), u ~ N($\\mu$, $\\sigma^2$)",
    )
    ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5))
    return fig, "fig6_mode_median_mean"


def make_tasks() -> None:
    from humanoid_envs.render import task_strip

    save_palette_png(task_strip(), DOCS / "h1hand_tasks.png")


def make_mode() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        (figure,) = [p for p in write_theory_figures(Path(tmp)) if p.stem == "fig3_action_bias"]
        save_palette_png(Image.open(figure), DOCS / "mode_vs_tanh_mu.png")


def make_analysis(runs: Path | None = None) -> None:
    """With `runs`, analyse that folder (made with TINY_RUN) instead of training again."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report"
        if runs is None:
            runs = Path(tmp) / "runs"
            train_tiny_runs(runs)
        subprocess.run(
            [sys.executable, "analyze.py", str(runs), "--out", str(report),
             "--normalize", "min-max"],
            cwd=ROOT, check=True,
        )  # fmt: skip
        figure = Image.open(report / "reward_curves.png")
        save_palette_png(figure, DOCS / "analyze_reward_curves.png")


def train_tiny_runs(runs: Path) -> None:
    for seed in SEEDS:
        name = f"Pendulum-v1__corrected__seed{seed}"
        subprocess.run(
            [sys.executable, "sac_corrected.py", *TINY_RUN, "--seed", str(seed),
             "--output-dir", str(runs), "--run-name", name],
            cwd=ROOT, check=True,
        )  # fmt: skip


MAKERS = {"tasks": make_tasks, "mode": make_mode, "analysis": make_analysis}


def main() -> None:
    parser = argparse.ArgumentParser(description="Regenerate the README's pictures in docs/.")
    parser.add_argument("which", nargs="*", help=f"any of {', '.join(MAKERS)} (default: all)")
    parser.add_argument(
        "--runs", type=Path, help="analysis: analyse this folder of runs instead of training"
    )
    parser.add_argument("--out", type=Path, metavar="DIR",
                        help="theory: the folder to write its PNGs into (created if missing)")
    args = parser.parse_args()
    which = args.which or list(MAKERS)
    if unknown := set(which) - {*MAKERS, "theory"}:
        parser.error(f"unknown figure(s) {sorted(unknown)}; choose from {[*MAKERS, 'theory']}")
    if "theory" in which and args.out is None:
        parser.error("theory needs --out DIR")
    for name in which:
        if name == "analysis":
            make_analysis(args.runs)
        elif name == "theory":
            for path in write_theory_figures(args.out):
                print(path)
        else:
            MAKERS[name]()


if __name__ == "__main__":
    main()
