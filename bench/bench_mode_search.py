"""Time the evaluation action: actor forward pass, tanh(mu), the paper's grid and the exact mode.

It first prints the exact solver's largest error in y against the tests' bisection reference
(float64, 1e6 random (mu, sigma) over |mu| <= 20, sigma in [1e-6, 10], and the near-double-root
corner sigma ~ 1/sqrt(2), mu ~ 0).

Run from the repository root: `python bench/bench_mode_search.py [--threads 1 2]`.
For one 61-dim action (batch 1) and for a batch of 256 actions it prints the median over
repeats of the mean time per call of each method, and the median over repeats of the ratios
the issue sets targets for. The four are timed one after the other inside each repeat, so a
load change on the machine shifts all of them alike. The actor is SAC's 256x256 ReLU MLP from a
164-dim observation to (mu, log_std) for 61 actuators; all tensors are float32 on the CPU.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from mode_search import mode_action  # noqa: E402
from tests.test_mode_search import bisection_mode, near_double_root_params, random_params  # noqa: E402

OBS_DIM, ACTION_DIM, HIDDEN = 164, 61, 256


def seconds_per_call(fn: Callable[[], object], calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - start) / calls


def bench(batch: int, repeats: int) -> list[dict[str, float]]:
    """Per repeat, seconds per call of the four ways to get an evaluation action."""
    torch.manual_seed(0)
    actor = torch.nn.Sequential(
        torch.nn.Linear(OBS_DIM, HIDDEN),
        torch.nn.ReLU(),
        torch.nn.Linear(HIDDEN, HIDDEN),
        torch.nn.ReLU(),
        torch.nn.Linear(HIDDEN, 2 * ACTION_DIM),
    )
    obs = torch.randn(batch, OBS_DIM)
    # mu ~ N(0, 1), log sigma ~ U(-3, 0.5): trained-policy spreads plus a bimodal share.
    mu = torch.randn(batch, ACTION_DIM)
    log_std = torch.empty(batch, ACTION_DIM).uniform_(-3.0, 0.5)
    methods = {
        "actor forward": (lambda: actor(obs), 1000 if batch == 1 else 50),
        "tanh(mu)": (lambda: torch.tanh(mu), 1000 if batch == 1 else 50),
        "grid mode": (lambda: mode_action(mu, log_std, "grid"), 20 if batch == 1 else 1),
        "exact mode": (lambda: mode_action(mu, log_std, "exact"), 1000 if batch == 1 else 50),
    }
    with torch.no_grad():
        for fn, _ in methods.values():  # warm-up
            fn()
        return [
            {name: seconds_per_call(fn, calls) for name, (fn, calls) in methods.items()}
            for _ in range(repeats)
        ]


def print_accuracy() -> None:
    mu, log_std = random_params(1_000_000, seed=11)
    hard_mu, hard_log_std = near_double_root_params()
    for name, (m, s) in {
        "random": (mu, log_std),
        "near double root": (hard_mu, hard_log_std),
    }.items():
        for dtype in (torch.float64, torch.float32):
            m_d, s_d = m.to(dtype), s.to(dtype)
            err = mode_action(m_d, s_d).double() - bisection_mode(m_d.double(), s_d.double())
            print(
                f"  {name:17s} {str(dtype):14s} n={m.numel():8d}  max |exact - bisection| "
                f"= {err.abs().max().item():.1e}"
            )


def report(threads: int, batch: int, runs: list[dict[str, float]]) -> None:
    print(f"\nthreads={threads}  batch={batch} x {ACTION_DIM} dims")
    for name in runs[0]:
        print(f"  {name:15s} {statistics.median(r[name] for r in runs) * 1e6:11.1f} us")
    ratios = {
        "grid / exact": ("grid mode", "exact mode"),
        "exact / actor": ("exact mode", "actor forward"),
        "exact / tanh": ("exact mode", "tanh(mu)"),
    }
    for label, (num, den) in ratios.items():
        print(f"  {label:15s} {statistics.median(r[num] / r[den] for r in runs):11.2f} x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch threads")
    parser.add_argument("--repeats", type=int, default=11, help="repeats per timing (median)")
    args = parser.parse_args()
    print("accuracy of the exact mode in y")
    print_accuracy()
    print(f"\ntorch {torch.__version__}, float32, CPU, median of {args.repeats} repeats")
    print(f"load average over the last minute at start: {os.getloadavg()[0]:.1f}")
    for threads in args.threads:
        torch.set_num_threads(threads)
        for batch in (1, 256):
            report(threads, batch, bench(batch, args.repeats))


if __name__ == "__main__":
    main()
