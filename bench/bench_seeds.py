"""CPU pace of K seeds in one process (--num-seeds K) against K single-seed processes side by side.

    .venv/bin/python bench/bench_seeds.py --env-id h1hand-powerlift-v0 --seeds 2 --repeats 2

Each side is a short sac_standard.py run (no evaluation, no checkpoint, one torch thread per
single-seed process, --batch-threads for the one process); the figure is the median steps/s of
its train.csv rows in the update phase (the first such row left out: warm-up), per seed (each
seed steps once per global step) and in all. The two sides run one after the other, alternating
within each repeat, so drift on a shared machine falls on both; the load average before each is
printed because other users' work counts here.
"""

import csv
import os
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import tyro

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Args:
    env_id: str = "h1hand-powerlift-v0"
    """the task to train"""
    seeds: int = 2
    """K: seeds in the one process, and single-seed processes on the other side"""
    learning_starts: int = 1000
    """random steps before the updates start"""
    total_timesteps: int = 3000
    """steps of each run (the update phase is the steps after --learning-starts)"""
    log_interval: int = 250
    """train.csv row interval: the update phase's rows are the samples"""
    repeats: int = 2
    """repeats of the pair of measurements; each is printed, then the medians"""
    script: str = "sac_standard.py"
    """the training script (sac_corrected.py trains the same way)"""
    batch_threads: int = 1
    """torch threads of the one process (its env workers idle while it updates, so it may use
    their cores); each single-seed process has one"""


def command(args: Args, out: str, name: str, flags: list[str], threads: int = 1) -> list[str]:
    """A run with evaluation and checkpoints off: only the training loop is timed."""
    return [sys.executable, str(ROOT / args.script), "--env-id", args.env_id,
            "--total-timesteps", str(args.total_timesteps),
            "--learning-starts", str(args.learning_starts),
            "--eval-interval", str(10 * args.total_timesteps), "--eval-workers", "0",
            "--checkpoint-interval", "0", "--log-interval", str(args.log_interval),
            "--print-interval", str(args.total_timesteps), "--torch-threads", str(threads),
            "--output-dir", out, "--run-name", name, *flags]


def update_phase_sps(run_dir: Path, learning_starts: int) -> float:
    """Median steps/s of the train.csv rows after the first row of the update phase."""
    with open(run_dir / "train.csv") as f:
        rows = [r for r in csv.DictReader(f) if int(r["global_step"]) > learning_starts]
    if len(rows) < 2:
        raise SystemExit(f"{run_dir}: fewer than two update-phase rows; raise --total-timesteps "
                         "or lower --log-interval")
    return statistics.median(float(r["sps"]) for r in rows[1:])


def run_together(commands: list[list[str]]) -> None:
    """Starts every command at once and waits for all (stderr shown if one fails)."""
    children = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
                for c in commands]
    errors = [child.communicate()[1] for child in children]
    for child, error in zip(children, errors, strict=True):
        if child.returncode != 0:
            raise SystemExit(error.decode())


def one_process(args: Args) -> float:
    """Steps/s per seed of --num-seeds K in one process (its K folders share one pace)."""
    with tempfile.TemporaryDirectory() as out:
        run_together([command(args, out, "k{seed}", ["--num-seeds", str(args.seeds)],
                              args.batch_threads)])
        return update_phase_sps(Path(out) / "k0", args.learning_starts)


def side_by_side(args: Args) -> list[float]:
    """Steps/s of each of K single-seed processes started together."""
    with tempfile.TemporaryDirectory() as out:
        run_together([command(args, out, f"s{k}", ["--seed", str(k)])
                      for k in range(args.seeds)])
        return [update_phase_sps(Path(out) / f"s{k}", args.learning_starts)
                for k in range(args.seeds)]


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


if __name__ == "__main__":
    args = tyro.cli(Args)
    k = args.seeds
    print(f"{args.env_id}, {args.script}, K = {k}, update phase steps "
          f"{args.learning_starts}-{args.total_timesteps}, {os.cpu_count()} cores", flush=True)
    batched, separate = [], []
    for repeat in range(args.repeats):
        # Alternate which side goes first, so that a trend in the machine's load is shared.
        for side in (("one", "many") if repeat % 2 == 0 else ("many", "one")):
            before = load()
            if side == "one":
                batched.append(one_process(args))
                print(f"  --num-seeds {k}, one process, {args.batch_threads} torch threads: "
                      f"{batched[-1]:6.1f} steps/s per seed, {k * batched[-1]:6.1f} in all "
                      f"({before})", flush=True)
            else:
                separate.append(sum(side_by_side(args)))
                print(f"  {k} single-seed processes:    {separate[-1] / k:6.1f} steps/s per seed, "
                      f"{separate[-1]:6.1f} in all ({before})", flush=True)
    one, many = statistics.median(batched) * k, statistics.median(separate)
    print(f"median in all: one process {one:.1f} steps/s, {k} processes {many:.1f} steps/s: "
          f"one process is {one / many:.2f}x", flush=True)
