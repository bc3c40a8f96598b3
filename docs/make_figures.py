"""Regenerate the README's pictures in docs/ with the project's own code:

    MUJOCO_GL=egl .venv/bin/python docs/make_figures.py            # all three, ~4 min on 2 cores
    MUJOCO_GL=egl .venv/bin/python docs/make_figures.py tasks mode # skip the training runs

- tasks: `python -m humanoid_envs.render`, every h1hand task's start state (h1hand_tasks.png);
- mode: mode_search.py's action-bias figure, the mode of tanh(u) against tanh(mu)
  (mode_vs_tanh_mu.png);
- analysis: three tiny sac_corrected.py runs on Pendulum-v1 (seeds 0-2, 8,000 steps), then
  analyze.py over them; its reward-curve figure (analyze_reward_curves.png). Illustrative of
  the report's layout, not a result.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

# Offscreen rendering without a display, as the tests render; read when mujoco is imported.
if sys.platform.startswith("linux"):
    os.environ.setdefault("MUJOCO_GL", "egl")

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # the scripts' modules import from the repository root

# Pendulum-v1 learns in a few thousand steps on a CPU; short enough to keep the docs cheap.
TINY_RUN = [
    "--env-id", "Pendulum-v1", "--total-timesteps", "8000", "--learning-starts", "1000",
    "--eval-interval", "500", "--eval-episodes", "5", "--checkpoint-interval", "0",
    "--no-cuda", "--print-interval", "4000",
]  # fmt: skip
SEEDS = (0, 1, 2)


def save_palette_png(image: Image.Image, path: Path) -> None:
    # Plots and renders have few distinct colours; a palette PNG is a third of the RGB one.
    image.convert("RGB").quantize(256, method=Image.Quantize.FASTOCTREE).save(path, optimize=True)
    print(f"wrote {path.relative_to(ROOT)} ({path.stat().st_size / 1024:.0f} KB)")


def make_tasks() -> None:
    from humanoid_envs.render import task_strip

    save_palette_png(task_strip(), DOCS / "h1hand_tasks.png")


def make_mode() -> None:
    from mode_search import write_figures

    with tempfile.TemporaryDirectory() as tmp:
        (figure,) = [p for p in write_figures(Path(tmp)) if p.stem == "fig3_action_bias"]
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
    args = parser.parse_args()
    which = args.which or list(MAKERS)
    if unknown := set(which) - set(MAKERS):
        parser.error(f"unknown figure(s) {sorted(unknown)}; choose from {list(MAKERS)}")
    for name in which:
        if name == "analysis":
            make_analysis(args.runs)
        else:
            MAKERS[name]()


if __name__ == "__main__":
    main()
