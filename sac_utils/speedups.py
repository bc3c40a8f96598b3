"""Speed, for both SAC scripts (docs/speed.md): torch.compile at start-up (compile_at_start), CUDA
graphs (cuda_graph), and building blocks with which the whole update compiles into one graph and
still runs fast eager: the gradient (grad), torch.optim.Adam's step as foreach ops (adam_step) and
a ReLU whose backward inductor runs fast (ReLU). The algorithm itself is in the scripts.
"""

import time
from collections.abc import Callable

import torch
import torch.nn as nn
import torch.utils._pytree as pytree

from sac_utils.cli import fail


class ReLUFromOutput(torch.autograd.Function):
    """ReLU whose backward multiplies by sign(output), 1 where it passed and 0 where it clipped:
    torch.relu's gradient, from a float tensor instead of a boolean mask of the input, which
    inductor's CPU code stores ~10x slower (docs/speed.md; the update has ten ReLUs)."""

    @staticmethod
    def forward(x: torch.Tensor) -> torch.Tensor:
        return x.clamp_min(0)

    @staticmethod
    def setup_context(ctx, inputs, output) -> None:  # torch.func.grad needs this form
        ctx.save_for_backward(output)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (output,) = ctx.saved_tensors
        return grad * output.sign()


class ReLU(nn.Module):
    """torch.relu, as ReLUFromOutput when compiled (the same gradient; eager, plain torch.relu)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ReLUFromOutput.apply(x) if torch.compiler.is_compiling() else torch.relu(x)


def grad(f: Callable) -> Callable:
    """torch.func.grad(f, has_aux=True): the gradient of f's first output with respect to its first
    argument (a pytree of tensors), and its second output, detached. Compiled, torch.func's
    (torch.autograd.grad would break the graph); eager, torch.autograd's: the same numbers ~1.3x
    faster on a CPU, without torch.func's dispatch around each of the update's ~300 small ops."""
    if torch.compiler.is_compiling():
        return torch.func.grad(f, has_aux=True)

    def autograd_grad(params, *args) -> tuple:
        with torch.enable_grad():
            total, aux = f(params, *args)
            leaves, spec = pytree.tree_flatten(params)
            grads = pytree.tree_unflatten(list(torch.autograd.grad(total, leaves)), spec)
        return grads, pytree.tree_map(torch.Tensor.detach, aux)

    return autograd_grad


def adam_step(params: list[torch.Tensor], grads: list[torch.Tensor], state: dict) -> None:
    """torch.optim.Adam's step (eps outside the square root, as optax's), in place on `state`
    (adam_state), as foreach ops that compile with the rest of the update."""
    beta1, beta2 = state["betas"]
    torch._foreach_add_(state["steps"], 1)
    torch._foreach_lerp_(state["exp_avgs"], grads, 1 - beta1)
    torch._foreach_mul_(state["exp_avg_sqs"], beta2)
    torch._foreach_addcmul_(state["exp_avg_sqs"], grads, grads, 1 - beta2)
    step = state["steps"][0]  # every parameter's count is the same
    bias_correction1, bias_correction2 = 1 - beta1**step, 1 - beta2**step
    denominators = torch._foreach_div(torch._foreach_sqrt(state["exp_avg_sqs"]),
                                      bias_correction2.sqrt())
    torch._foreach_add_(denominators, state["eps"])
    steps = torch._foreach_div(state["exp_avgs"], denominators)
    torch._foreach_mul_(steps, state["lr"] / bias_correction1)
    torch._foreach_sub_(params, steps)


def adam_state(optimizer: torch.optim.Optimizer) -> dict:
    """A torch.optim.Adam's tensors (created as its first step would) and settings, for adam_step:
    the optimizer keeps holding them, for checkpoints."""
    group = optimizer.param_groups[0]
    for p in group["params"]:
        if not optimizer.state[p]:
            optimizer.state[p] = {"step": torch.zeros((), device=p.device),
                                  "exp_avg": torch.zeros_like(p),
                                  "exp_avg_sq": torch.zeros_like(p)}
    states = [optimizer.state[p] for p in group["params"]]
    return {"steps": [s["step"] for s in states], "exp_avgs": [s["exp_avg"] for s in states],
            "exp_avg_sqs": [s["exp_avg_sq"] for s in states], "lr": group["lr"],
            "betas": group["betas"], "eps": group["eps"]}


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
    """fn, captured as a CUDA graph at its first call and replayed at every call: the tensors of
    the arguments are copied into the graph's inputs; the outputs are overwritten by the next
    replay. So that the capture's eager warm-up calls do not change the run, the tensors of
    `restore` and the random generators are put back afterwards (optimizer states the warm-up
    created zeroed): a run is the same whenever the capture happens (at start or after a resume)."""
    graph, inputs, outputs = None, (), None

    def replay(*args):
        nonlocal graph, inputs, outputs
        if graph is None:
            inputs = pytree.tree_map(torch.clone, args)
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
        for static, arg in zip(pytree.tree_leaves(inputs), pytree.tree_leaves(args), strict=True):
            static.copy_(arg)
        graph.replay()
        return outputs

    return replay


def compile_at_start(fn: Callable, example: tuple, restore: tuple, name: str) -> Callable:
    """fn compiled whole (fullgraph) and called once on `example` at start-up, so that the cost and
    any failure show at once (the tensors of `restore` are put back). Inductor caches its work (in
    /tmp): a second run on the machine compiles in a fraction of the time."""
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
