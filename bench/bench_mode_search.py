"""Time the evaluation action: actor forward pass, tanh(mu), the paper's grid and the exact mode.

Run from the repository root: `python bench/bench_mode_search.py [--threads 1 2]`.
Prints the median over repeats of the mean time per call, for one 61-dim action (batch 1) and
for a batch of 256 actions, and the ratios the issue sets targets for. The actor is SAC's
256x256 ReLU MLP from a 164-dim observation to (mu, log_std) for 61 actuators.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from mode_search import mode_action  # noqa: E402

OBS_DIM, ACTION_DIM, HIDDEN = 164, 61, 256


def median_seconds(fn: Callable[[], object], calls: int, repeats: int) -> float:
    """Median over `repeats` of the mean wall time of `calls` back-to-back calls."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def bench(batch: int, repeats: int) -> dict[str, float]:
    """Seconds per call of the four ways to get an evaluation action for `batch` states."""
    torch.manual_seed(0)
    actor = torch.nn.Sequential(
        torch.nn.Linear(OBS_DIM, HIDDEN),
        torch.nn.ReLU(),
        torch.nn.Linear(HIDDEN, HIDDEN),
        torch.nn.ReLU(),
        torch.nn.Linear(HIDDEN, 2 * ACTION_DIM),
    )
    obs = torch.randn(batch, OBS_DIM)
    # A spread like a trained policy's: mu ~ N(0, 1), log sigma ~ U(-3, 0.5) (bimodal included).
    mu = torch.randn(batch, ACTION_DIM)
    log_std = torch.empty(batch, ACTION_DIM).uniform_(-3.0, 0.5)
    fast_calls = 2000 if batch == 1 else 200
    grid_calls = 50 if batch == 1 else 1
    with torch.no_grad():
        return {
            "actor forward": median_seconds(lambda: actor(obs), fast_calls, repeats),
            "tanh(mu)": median_seconds(lambda: torch.tanh(mu), fast_calls, repeats),
            "grid mode": median_seconds(
                lambda: mode_action(mu, log_std, "grid"), grid_calls, repeats
            ),
            "exact mode": median_seconds(
                lambda: mode_action(mu, log_std, "exact"), fast_calls, repeats
            ),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch threads")
    parser.add_argument("--repeats", type=int, default=7, help="repeats per timing (median)")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, float32, CPU, median of {args.repeats} repeats")
    for threads in args.threads:
        torch.set_num_threads(threads)
        for batch in (1, 256):
            t = bench(batch, args.repeats)
            print(f"\nthreads={threads} batch={batch} x {ACTION_DIM} dims")
            for name, seconds in t.items():
                print(f"  {name:14s} {seconds * 1e6:12.1f} us")
            print(f"  grid / exact   {t['grid mode'] / t['exact mode']:12.1f} x")
            print(f"  exact / actor  {t['exact mode'] / t['actor forward']:12.2f} x")


if __name__ == "__main__":
    main()
