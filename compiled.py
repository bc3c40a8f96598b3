"""What makes the SAC scripts fast, kept out of them: CUDA graphs and torch.compile at start-up.

Both scripts import these; none of it is the algorithm (docs/speed.md).
"""

import time
from collections.abc import Callable

import torch
import torch.nn as nn

from run_folder import fail


# CUDA graphs (LeanRL's recipe with torch.cuda.graphs): eager PyTorch launches ~300 small kernels
# per update, and on a GPU their launch cost, not the arithmetic, sets the speed. A graph records
# the kernels once and replays them with one launch.
def training_state(*objects: nn.Module | torch.optim.Optimizer | torch.Tensor) -> list:
    """Every tensor that a training step may change: parameters, buffers, optimizer states."""
    tensors = []
    for obj in objects:
        if isinstance(obj, torch.optim.Optimizer):
            tensors += [v for state in obj.state.values() for v in state.values()
                        if torch.is_tensor(v)]
        elif isinstance(obj, nn.Module):
            tensors += list(obj.state_dict(keep_vars=True).values())
        else:
            tensors.append(obj)
    return tensors


def cuda_graph(fn: Callable, restore: tuple = ()) -> Callable:
    """fn, captured as a CUDA graph at its first call and replayed at every call.

    The returned function copies its tensor arguments into the graph's inputs and returns the
    graph's outputs (overwritten by the next replay). A capture needs a few eager warm-up calls
    first; so that they do not change the run, the tensors of `restore` (modules, optimizers,
    tensors) and the random generators are put back afterwards, and optimizer states that the
    warm-up created are zeroed, as a fresh optimizer's are. A run is then the same whenever the
    capture happens (at the start of learning, or after a resume)."""
    graph, inputs, outputs = None, (), None

    def replay(*args: torch.Tensor):
        nonlocal graph, inputs, outputs
        if graph is None:
            inputs = tuple(a.clone() for a in args)
            saved = [(t, t.detach().clone()) for t in training_state(*restore)]
            rng = torch.get_rng_state(), torch.cuda.get_rng_state()
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                for _ in range(3):
                    fn(*inputs)
            torch.cuda.current_stream().wait_stream(side)
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph):
                outputs = fn(*inputs)
            with torch.no_grad():
                for t in training_state(*restore):
                    t.zero_()
                for t, value in saved:
                    t.copy_(value)
            torch.set_rng_state(rng[0])
            torch.cuda.set_rng_state(rng[1])
        for static, arg in zip(inputs, args, strict=True):
            static.copy_(arg)
        graph.replay()
        return outputs

    return replay



def compile_at_start(fn: Callable, example: tuple, restore: tuple, name: str) -> Callable:
    """fn compiled whole (torch.compile, fullgraph: one graph, no breaks) and called once, at
    start-up, on the `example` arguments, so that the compile's cost and any failure show at
    once, not after learning_starts steps; the tensors of `restore` are put back afterwards.
    Inductor caches what it compiled (in /tmp by default): a second run or a resume on the same
    machine compiles in a fraction of the time."""
    compiled = torch.compile(fn, fullgraph=True)
    saved = [(t, t.detach().clone()) for t in training_state(*restore)]
    start = time.time()
    try:
        compiled(*example)
    except Exception as error:  # inductor's errors run to pages: the first line, and the fixes
        cause = next((line for line in str(error).splitlines() if line.strip()), "")[:300]
        fail(f"compiling {name} failed ({type(error).__name__}: {cause}); run with "
             "--no-compile, or if a C++ compiler or Python's headers are missing, install them "
             "(apt-get install g++ python3-dev)")
    with torch.no_grad():
        for t, value in saved:
            t.copy_(value)
    print(f"compiled {name} in {time.time() - start:.1f} s", flush=True)
    return compiled
