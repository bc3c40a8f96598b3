"""Training speed of one run on each env id of a sweep.py preset: the measurement behind the
table of speeds in docs/sweep.md, which `sweep.py --dry-run --steps-per-second` takes.

    .venv/bin/python bench/bench_presets.py --preset dimensions

Per env id: bench_sac.py's training-loop cost at the batch size the preset's runs get
(process CPU seconds of a sac_standard.py run with --loop-steps steps after 1,000 start steps,
minus a run that stops one step after the start steps, over the steps between; one torch
thread; no evaluation, no checkpoint), median over --repeats. CPU time rather than wall time, so
that a shared machine inflates it less; it counts neither the evaluation rounds (10 episodes of
mode and 10 of tanh(mu) every 10,000 steps) nor the process start.
"""

import statistics
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import bench_sac  # noqa: E402

from sweep import PRESETS, Preset  # noqa: E402


@dataclass
class Args:
    preset: Literal["paper", "dimensions", "classic"] = "dimensions"
    """the sweep.py preset whose env ids are timed"""
    env_ids: tuple[str, ...] = ()
    """time only these env ids (default: all of the preset's)"""
    loop_steps: int = 2000
    """training-loop steps timed after the start steps"""
    repeats: int = 1
    """timings per env id; the median is printed"""


def batch_size(preset: Preset) -> int:
    """The batch size of the preset's runs: its --batch-size flag, else the scripts' default."""
    flags = list(preset.run_args)
    if "--batch-size" in flags:
        return int(flags[flags.index("--batch-size") + 1])
    return bench_sac.sac_standard.Args.batch_size


def steps_per_second(env_id: str, batch: int, loop_steps: int, repeats: int) -> float:
    """One run's training-loop steps per CPU second on env_id (bench_sac.py's measurement)."""
    bench = bench_sac.Args(env_id=env_id, batch_size=batch, loop_steps=loop_steps, repeats=2)
    return 1 / statistics.median(bench_sac.loop_seconds_per_step(bench) for _ in range(repeats))


if __name__ == "__main__":
    args = tyro.cli(Args)
    preset = PRESETS[args.preset]
    batch = batch_size(preset)
    for env_id in args.env_ids or preset.env_ids:
        speed = steps_per_second(env_id, batch, args.loop_steps, args.repeats)
        print(f"{env_id:<28} batch {batch}: {speed:6.0f} steps/s "
              f"({1e3 / speed:5.2f} ms of CPU per step)", flush=True)
