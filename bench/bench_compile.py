"""What stands between a whole-update `torch.compile` and a faster SAC update on a CPU (issue 26).

Run from the repository root: `python bench/bench_compile.py [--repeats 2000]`, on a quiet
machine, one thread. It times, eager and compiled (inductor, `fullgraph=True`), the pointwise
work one hidden layer of the update does around its matmul at the paper's shape (batch 64, width
256): ReLU alone, and ReLU plus the boolean mask its backward keeps. A compiled update that
differentiates through `torch.func` saves that mask as a bool tensor; inductor's CPU code stores
it element by element, and the update has ten such layers. A ReLU whose backward multiplies by
sign(output) instead keeps no boolean tensor (last line).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import torch


def per_call_us(fn: Callable, x: torch.Tensor, repeats: int) -> float:
    """Median over 5 timings of the mean wall-clock microseconds per call."""
    for _ in range(100):
        fn(x)
    timings = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            fn(x)
        timings.append((time.perf_counter() - start) / repeats * 1e6)
    return sorted(timings)[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=2000, help="calls per timing")
    args = parser.parse_args()
    torch.set_num_threads(1)
    x = torch.randn(1, 64, 256)  # a batch of 64 at a hidden layer, as the scripts' Linear has it
    bias = torch.randn(1, 1, 256)
    kernels = {
        "relu(x + b)": lambda x: torch.relu(x + bias),
        "relu(x + b) and its mask (bool)": lambda x: (torch.relu(x + bias), x + bias <= 0),
        "the mask alone (bool)": lambda x: x <= 0,
        "the mask alone (float32)": lambda x: (x <= 0).float(),
        # ReLU's derivative from its output with no comparison: sign(relu(x)) is 1 or 0.
        "relu(x + b) and sign of it (float32)": lambda x: (torch.relu(x + bias),
                                                           torch.relu(x + bias).sign()),
    }
    print(f"torch {torch.__version__}, 1 thread, a (1, 64, 256) float32 input; microseconds per "
          "call, eager / compiled")
    for name, fn in kernels.items():
        eager = per_call_us(fn, x, args.repeats)
        compiled = per_call_us(torch.compile(fn, fullgraph=True), x, args.repeats)
        print(f"{name:38s} {eager:7.1f} / {compiled:7.1f}")


if __name__ == "__main__":
    main()
