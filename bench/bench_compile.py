"""What stands between a whole-update `torch.compile` and a faster SAC update on a CPU (issue 26).

Run from the repository root: `python bench/bench_compile.py [--repeats 2000]`, on a quiet
machine, one thread. It times, eager and compiled (inductor, `fullgraph=True`), the pointwise
work one hidden layer of the update does around its matmul at the paper's shape (batch 64, width
256): ReLU alone, and ReLU plus the boolean mask its backward keeps. A compiled update that
differentiates through `torch.func` saves that mask as a bool tensor; inductor's CPU code stores
it element by element, and the update has ten such layers. A ReLU whose backward multiplies by
sign(output) instead keeps no boolean tensor.

Then Adam's step (compiled.adam_step) on the parameter shapes of h1hand-powerlift-v0's actor
and twin critics, compiled: with its bias corrections stacked into one tensor
(compiled.bias_corrections, the scripts'), against the same step with each correction a scalar
formula, which inductor inlines into the loop over every parameter's elements (two powers per
vector of 16 floats).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from unittest import mock

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import compiled  # noqa: E402

# (in, out) of each layer, seed axis first, as the scripts' SeedLinear holds them: powerlift's
# actor (164 observations, 61 actions: mean and log-std heads) and its two critics.
POWERLIFT_SHAPES = [(1, 164, 256), (1, 1, 256), (1, 256, 256), (1, 1, 256), (1, 256, 61),
                    (1, 1, 61), (1, 256, 61), (1, 1, 61)] + 2 * [
    (1, 225, 256), (1, 1, 256), (1, 256, 256), (1, 1, 256), (1, 256, 1), (1, 1, 1)]


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
    x = torch.randn(1, 64, 256)  # one seed's batch at one hidden layer
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
        compiled_us = per_call_us(torch.compile(fn, fullgraph=True), x, args.repeats)
        print(f"{name:38s} {eager:7.1f} / {compiled_us:7.1f}")
    print("\nAdam's step on powerlift's actor and critic parameters, compiled, microseconds per "
          "call")
    for name, corrections in (("bias corrections stacked (the scripts')",
                               compiled.bias_corrections),
                              ("bias corrections inlined", inlined_bias_corrections)):
        with mock.patch.object(compiled, "bias_corrections", corrections):
            print(f"{name:38s} {adam_step_us(args.repeats // 10):7.1f}")


def inlined_bias_corrections(step: torch.Tensor, lr: float, beta1: float, beta2: float) -> tuple:
    """compiled.bias_corrections' two values, each its own 0-d formula of the step."""
    return lr / (1 - beta1**step), (1 - beta2**step).sqrt()


def adam_step_us(repeats: int) -> float:
    """compiled.adam_step compiled afresh, on POWERLIFT_SHAPES, in microseconds per call."""
    torch._dynamo.reset()
    params = [torch.randn(shape) for shape in POWERLIFT_SHAPES]
    grads = [torch.randn(shape) for shape in POWERLIFT_SHAPES]
    state = compiled.adam_state(torch.optim.Adam(params, lr=3e-4))
    step = torch.compile(torch.no_grad()(compiled.adam_step), fullgraph=True)
    return per_call_us(lambda _: step(params, grads, state), None, repeats)


if __name__ == "__main__":
    main()
