"""Does the compiled update's per-call overhead pay to cut? (issue 26)

    .venv/bin/python bench/bench_update_overhead.py --env-id Hopper-v5

Times the scripts' compiled update (batch sampling included, make_train_step), built the scripts'
way, against the same update compiled with less per-call work around the graph: Dynamo's guards
cut to the tensor guards or skipped altogether (torch.compiler's *_unsafe guard filters; the
update is always called with the same tensors, so nothing they guard could change), and
inductor's C++ wrapper (the graph's ~100 kernel calls made from C++ instead of Python); and
inductor's max-autotune, whose C++ GEMM template may replace ATen's matmuls. The
variants are timed in turns, round after round, so that a shared machine's load falls on all of
them alike; process CPU seconds, one thread. Prints the median and the best round per update.

With --eager, nothing is compiled: the scripts' sac_update (its gradient from torch.autograd, as
compiled.grad takes it uncompiled) against the same update with torch.func.grad's gradient (what
the compiled graph is traced from), and the largest difference of their logged losses over the
first 30 updates from one seed.
"""

import functools
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import gymnasium as gym
import torch
import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench_sac import build_learner, random_buffer  # noqa: E402

import humanoid_envs  # noqa: E402, F401  (registers the h1hand tasks)
import sac_standard  # noqa: E402
from compiled import make_train_step  # noqa: E402
from sac_standard import learner_tensors, sac_update  # noqa: E402

VARIANTS = {
    "scripts' compile (default guards)": {},
    "tensor guards only": {"guard_filter_fn": torch.compiler.keep_tensor_guards_unsafe},
    "no guards": {"guard_filter_fn": torch.compiler.skip_all_guards_unsafe},
    "C++ wrapper": {"cpp_wrapper": True},
    # Inductor's own C++ GEMM template, autotuned against ATen's matmuls at the first call.
    "max-autotune": {"max_autotune": True, "max_autotune_gemm_backends": "CPP,ATEN"},
}


@dataclass
class Args:
    env_id: str = "Hopper-v5"
    """the task whose dimensions the update has"""
    rounds: int = 15
    """timing rounds; each times every variant once"""
    updates: int = 200
    """updates per variant per round"""
    batch_size: int = 64
    """the paper's batch"""
    eager: bool = False
    """time the uncompiled update's two gradients instead (see above)"""


def update_with_func_grad(*args, **kwargs) -> tuple:
    """The scripts' sac_update, its gradient taken by torch.func.grad also when not compiled."""
    with mock.patch.object(sac_standard, "grad", lambda f: torch.func.grad(f, has_aux=True)):
        return sac_update(*args, **kwargs)


def train_step(env: gym.Env, rb, options: dict | None, batch_size: int, update_fn=sac_update):
    """A fresh learner's update (seed 0), compiled whole with these torch.compile options
    (None: not compiled)."""
    torch.manual_seed(0)
    actor, qf, qf_target, log_alpha, optimizers = build_learner(env)
    tensors = learner_tensors(actor, qf, qf_target, log_alpha, *optimizers)
    update = functools.partial(update_fn, actor=actor, qf=qf, gamma=0.99, tau=0.005,
                               target_entropy=-rb.action_dim / 2)
    if options is not None:
        update = torch.compile(update, fullgraph=True, options=options or None)
    return make_train_step(rb, lambda batch, noise: update(tensors, batch, noise), batch_size,
                           torch.device("cpu"), False, ())


def main(args: Args) -> None:
    torch.set_num_threads(1)
    env = gym.make(args.env_id)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    rb = random_buffer(20_000, obs_dim, action_dim, torch.device("cpu"))
    steps = {}
    if args.eager:
        for name, update_fn in (("eager, the scripts' (torch.autograd)", sac_update),
                                ("eager, torch.func.grad", update_with_func_grad)):
            steps[name] = train_step(env, rb, None, args.batch_size, update_fn)
        logs = []
        for step in steps.values():
            torch.manual_seed(1)  # the same batches and noise for both
            logs.append([torch.stack([t.float().mean() for t in step()]) for _ in range(30)])
        print("largest difference of the logged losses over 30 updates: "
              f"{max((a - b).abs().max().item() for a, b in zip(*logs, strict=True)):.2e}")
    for name, options in ({} if args.eager else VARIANTS).items():
        torch._dynamo.reset()  # each variant compiles its own graph
        steps[name] = train_step(env, rb, options, args.batch_size)
    for step in steps.values():
        for _ in range(20):  # compile, then warm up
            step()
    ms = {name: [] for name in steps}
    for _ in range(args.rounds):
        for name, step in steps.items():
            start = time.process_time()
            for _ in range(args.updates):
                step()
            ms[name].append((time.process_time() - start) / args.updates * 1e3)
    print(f"{args.env_id}: ms per update (sampling included), {args.rounds} rounds of "
          f"{args.updates}")
    for name, times in ms.items():
        print(f"  {name:36s} median {statistics.median(times):.3f}  best {min(times):.3f}")


if __name__ == "__main__":
    main(tyro.cli(Args))
