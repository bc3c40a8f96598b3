"""What evaluation costs training, now that it runs beside it (sac_utils/eval_rounds.py).

Per task: the training pace (steps/s of the update phase, per seed and in all) of `--seeds`
runs of sac_corrected.py side by side, with evaluation off, with the paired two actions (mode,
tanh(mu)) and with four (`--eval-selectors mean q_best`), every episode at its time limit
(bench/endless.py ignores termination: the worst case); the steps a seed reaches in
`--budget-minutes`; and the time of one worst-case round, in-process, on one thread.

    python bench/bench_eval.py --tasks Hopper-v5 --seeds 2 --total-timesteps 6000 \\
        --learning-starts 1000 --eval-interval 2000        # a small run on a CPU
    python bench/bench_eval.py                              # the protocol's setting, GPU node
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import torch
import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import bench.endless  # noqa: E402, F401  (registers the Endless-* envs)
import sac_corrected  # noqa: E402
from sac_utils.eval_rounds import Round, eval_seeds, run_round  # noqa: E402


@dataclass
class Args:
    tasks: tuple[str, ...] = ("h1hand-bookshelf_simple-v0", "Hopper-v5", "HalfCheetah-v5",
                              "Ant-v5", "Humanoid-v5")
    """env ids (each run as its Endless- version)"""
    seeds: int = 5
    """runs of each task side by side (one process each)"""
    total_timesteps: int = 40_000
    """steps of each run"""
    learning_starts: int = 10_000
    """random steps before the updates (the pace is measured after them)"""
    eval_interval: int = 10_000
    """the protocol's: 10 episodes every 10,000 steps"""
    eval_episodes: int = 10
    budget_minutes: float = 25.0
    """print the steps a seed reaches in this many minutes at the measured pace"""
    extra: str = ""
    """more flags for every run, e.g. --extra='--no-cuda'"""


def run_grid(args: Args, task: str, eval_flags: list[str], out: Path) -> list[float]:
    """Steps/s of each seed's update phase (median of its train.csv rows after the start)."""
    cores = len(os.sched_getaffinity(0))
    workers = max(1, (cores - args.seeds) // args.seeds)
    processes = [subprocess.Popen(
        [sys.executable, str(ROOT / "sac_corrected.py"), "--env-id",
         f"bench.endless:Endless-{task}", "--seed", str(seed), "--total-timesteps",
         str(args.total_timesteps),
         "--learning-starts", str(args.learning_starts), "--eval-episodes",
         str(args.eval_episodes), "--eval-workers", str(workers), "--checkpoint-interval", "0",
         "--print-interval", str(args.total_timesteps), "--output-dir", str(out),
         "--run-name", f"seed{seed}", *eval_flags, *args.extra.split()],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        for seed in range(args.seeds)]
    for p in processes:
        _, err = p.communicate()
        if p.returncode != 0:
            raise SystemExit(f"a run failed:\n{err[-2000:]}")
    paces = []
    for seed in range(args.seeds):
        lines = (out / f"seed{seed}" / "train.csv").read_text().splitlines()
        header = lines[0].split(",")
        rows = [dict(zip(header, line.split(","), strict=True)) for line in lines[1:]]
        paces.append(statistics.median(float(r["sps"]) for r in rows
                                       if int(r["global_step"]) > args.learning_starts))
    return paces


def worst_round_seconds(task: str, actions: dict[str, str], episodes: int) -> tuple[float, int]:
    """Seconds and env steps of one worst-case round, in-process, of an untrained actor (and
    critic, for q_best) as sac_corrected.py builds them (make_agent, its default sizes)."""
    env = gym.make(task)
    agent = sac_corrected.make_agent(sac_corrected.Args(env_id=task),
                                     env.observation_space.shape[0], env.action_space,
                                     torch.device("cpu"))
    critic = agent["qf"] if "q_best" in actions.values() else None
    round_ = Round(f"bench.endless:Endless-{task}", eval_seeds(0, 1, episodes), actions,
                   agent["actor"], critic)
    start = time.perf_counter()
    result = run_round(round_)
    return time.perf_counter() - start, sum(sum(result[p]["lengths"]) for p in actions)


def main(args: Args) -> None:
    cores = len(os.sched_getaffinity(0))
    print(f"{cores} cores; {args.seeds} runs per task side by side, {args.total_timesteps:,} "
          f"steps each, {args.eval_episodes} episodes every {args.eval_interval:,} steps, every "
          "episode at its time limit")
    settings = {"evaluation off": ["--eval-interval", str(args.total_timesteps + 1)],
                "mode + tanh(mu)": ["--eval-interval", str(args.eval_interval)],
                "four actions": ["--eval-interval", str(args.eval_interval), "--eval-selectors",
                                 "mean", "q_best"]}
    for task in args.tasks:
        paces = {}
        for name, flags in settings.items():
            with tempfile.TemporaryDirectory() as out:
                paces[name] = run_grid(args, task, flags, Path(out))
        off = statistics.mean(paces["evaluation off"])
        for name, per_seed in paces.items():
            pace = statistics.mean(per_seed)
            print(f"{task:<28} {name:<16} {pace:7.1f} steps/s per seed ({pace * args.seeds:8.1f} "
                  f"in all), {100 * pace / off:5.1f}% of evaluation off; "
                  f"{pace * 60 * args.budget_minutes:>11,.0f} steps in {args.budget_minutes:g} min")
        for label, actions in (("2 actions", {"": "mode", "tanh_mu_": "tanh_mu"}),
                               ("4 actions", {"": "mode", "tanh_mu_": "tanh_mu", "mean_": "mean",
                                              "q_best_": "q_best"})):
            seconds, steps = worst_round_seconds(task, actions, args.eval_episodes)
            print(f"{task:<28} one worst-case round, {label}: {seconds:6.1f} s for {steps:,} env "
                  f"steps ({1e3 * seconds / steps:.2f} ms per step, one thread)")


if __name__ == "__main__":
    main(tyro.cli(Args))
