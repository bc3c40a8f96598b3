"""Speed, for both SAC scripts (docs/speed.md): torch.compile at start-up (compile_at_start), the
compiled update (compiled_update) and CUDA graphs (cuda_graph). The algorithm is the scripts':
compiled_update takes the gradients of the scripts' own loss functions, so `--compile` and
`--no-compile` train alike (tests/test_compile.py pins them to each other).
"""

import time
from collections.abc import Callable, Iterable

import torch
import torch.nn as nn
import torch.utils._pytree as pytree

from sac_utils.cli import fail


def compile_at_start(fn: Callable, example: tuple, restore: Iterable = (),
                     name: str = "acting") -> Callable:
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


# The compiled update. torch.compile of the scripts' sac_update as it reads (three backward calls
# and three optimizer steps) runs ~1.5x slower on a CPU than this (docs/speed.md): the same losses,
# each one's gradient with respect to its own parameters by torch.func, and Adam's step as foreach
# ops, so that the whole update is one function of tensors and compiles into one graph.


class Bound:
    """A module run on the given parameters (torch.func.functional_call) wherever a loss calls it;
    its other attributes (an Actor's squash, which reads buffers only) are the module's."""

    def __init__(self, module: nn.Module, params: dict[str, torch.Tensor]):
        self.module, self.params = module, params

    def __call__(self, *args: torch.Tensor):
        return torch.func.functional_call(self.module, self.params, args)

    def __getattr__(self, name: str):
        return getattr(self.module, name)


def adam_state(optimizer: torch.optim.Optimizer) -> dict:
    """A torch.optim.Adam's tensors (created as its first step would) and settings, for adam_step:
    the optimizer keeps holding them, for checkpoints and for the uncompiled path."""
    group = optimizer.param_groups[0]
    for p in group["params"]:
        if not optimizer.state[p]:
            optimizer.state[p] = {"step": torch.zeros((), device=p.device),
                                  "exp_avg": torch.zeros_like(p),
                                  "exp_avg_sq": torch.zeros_like(p)}
    return {"params": list(group["params"]), "lr": group["lr"], "betas": group["betas"],
            "eps": group["eps"], **{f"{k}s": [optimizer.state[p][k] for p in group["params"]]
                                    for k in ("step", "exp_avg", "exp_avg_sq")}}


def adam_step(grads: list[torch.Tensor], state: dict) -> None:
    """torch.optim.Adam's step (eps outside the square root, as optax's) on state["params"], in
    place on `state` (adam_state), as foreach ops that compile with the rest of the update."""
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
    torch._foreach_sub_(state["params"], steps)


def functional_update(agent: dict, losses: tuple[Callable, Callable, Callable], gamma: float,
                      tau: float, target_entropy: float) -> Callable:
    """The script's sac_update, computed otherwise: update(batch, noise) -> the same logs. Call
    it after a checkpoint's load (it holds the optimizers' state tensors)."""
    critic_loss, actor_loss, alpha_loss = losses
    actor, qf, qf_target, log_alpha = (agent[k] for k in ("actor", "qf", "qf_target", "log_alpha"))
    actor_params, qf_params = dict(actor.named_parameters()), dict(qf.named_parameters())
    states = [adam_state(agent[k]) for k in ("actor_optimizer", "q_optimizer", "alpha_optimizer")]
    grad = torch.func.grad_and_value

    @torch.no_grad()  # torch.func.grad turns gradients on for the losses alone
    def update(batch: tuple[torch.Tensor, ...], noise: torch.Tensor) -> tuple[torch.Tensor, ...]:
        alpha = log_alpha.exp()
        frozen_actor = Bound(actor, {k: p.detach() for k, p in actor_params.items()})
        frozen_qf = Bound(qf, {k: p.detach() for k, p in qf_params.items()})
        qf_grads, (_, (qf_losses, qf_values)) = grad(lambda p: critic_loss(
            Bound(qf, p), qf_target, frozen_actor, alpha, batch, noise[0], gamma),
            has_aux=True)(qf_params)
        actor_grads, (pi_loss, log_pi) = grad(lambda p: actor_loss(
            Bound(actor, p), frozen_qf, alpha, batch[0], noise[1]), has_aux=True)(actor_params)
        alpha_grad, temperature_loss = grad(lambda p: alpha_loss(p, log_pi, target_entropy))(
            log_alpha)
        # The target towards the critics before their step, then the three Adam steps.
        torch._foreach_lerp_(list(qf_target.parameters()), list(qf_params.values()), tau)
        adam_step(list(qf_grads.values()), states[1])
        adam_step(list(actor_grads.values()), states[0])
        adam_step([alpha_grad], states[2])
        return qf_losses, qf_values, pi_loss, alpha, temperature_loss, log_pi

    return update


def compiled_update(agent: dict, losses: tuple[Callable, Callable, Callable], gamma: float,
                    tau: float, target_entropy: float, shapes: tuple[int, int, int],
                    device: torch.device) -> Callable:
    """functional_update, compiled whole at start-up; shapes: (batch, obs, action) sizes."""
    b, o, a = shapes
    batch = tuple(torch.zeros(s, device=device) for s in ((b, o), (b, a), (b,), (b, o), (b,)))
    return compile_at_start(functional_update(agent, losses, gamma, tau, target_entropy),
                            (batch, torch.zeros((2, b, a), device=device)), agent.values(),
                            "the update")


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


def cuda_graph(fn: Callable, restore: Iterable = ()) -> Callable:
    """fn, captured as a CUDA graph at its first call and replayed at every call: the tensors of
    the arguments are copied into the graph's inputs; the outputs are overwritten by the next
    replay. So that the capture's eager warm-up calls do not change the run, the tensors of
    `restore` and the random generators are put back afterwards (optimizer states the warm-up
    created zeroed): a run is the same whenever the capture happens (at start or after a resume)."""
    graph, inputs, outputs, restore = None, (), None, tuple(restore)

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
