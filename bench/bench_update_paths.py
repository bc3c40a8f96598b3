"""Milliseconds of process CPU time per SAC update, one thread, batch 64, 256x256 networks, on
fixed random batches (5 x N updates after 30 warm-up ones; min and median of the 5), for the
scripts of a checkout ROOT: MODE `compiled` (the default --compile path), `eager` (the textbook
sac_update, --no-compile) or `functional` (the compiled path's function, uncompiled). ROOT may be
an older commit's checkout (`git worktree add /tmp/old 3af1737`; before issue 87 the scripts had
agent_tensors and a functional sac_update, which this runs too), so both are timed alike:

    python bench/bench_update_paths.py ROOT MODE OBS_DIM ACTION_DIM N

Run on a quiet machine (pause training runs with SIGSTOP): a process beside it moves the figures
by 25% or more even in CPU time.
"""

import functools
import sys
import time


def main() -> None:
    root, mode = sys.argv[1], sys.argv[2]
    obs, act, n = (int(a) for a in sys.argv[3:6])
    sys.path.insert(0, root)
    import gymnasium as gym
    import numpy as np
    import torch

    import sac_standard as sac
    from sac_utils import speedups

    torch.set_num_threads(1)
    bs, gamma, tau, target_entropy = 64, 0.99, 0.005, -0.5 * act
    space = gym.spaces.Box(-1.0, 1.0, (act,), np.float32)
    agent = sac.make_agent(sac.Args(), obs, space, torch.device("cpu"))
    g = torch.Generator().manual_seed(1)
    batches = [((torch.randn(bs, obs, generator=g), torch.rand(bs, act, generator=g) * 2 - 1,
                 torch.randn(bs, generator=g), torch.randn(bs, obs, generator=g),
                 (torch.rand(bs, generator=g) > 0.05).float()),
                torch.randn(2, bs, act, generator=g)) for _ in range(20)]
    if hasattr(sac, "agent_tensors"):  # the scripts before issue 87
        tensors = sac.agent_tensors(**agent)
        update = functools.partial(sac.sac_update, actor=agent["actor"], qf=agent["qf"],
                                   gamma=gamma, tau=tau, target_entropy=target_entropy)
        if mode == "compiled":
            zeros = tuple(torch.zeros(s) for s in ((bs, obs), (bs, act), (bs,), (bs, obs), (bs,)))
            update = speedups.compile_at_start(update, (tensors, zeros, torch.zeros(2, bs, act)),
                                               tuple(agent.values()), "the update")
        update = functools.partial(update, tensors)
    else:
        losses = (sac.critic_loss, sac.actor_loss, sac.alpha_loss)
        if mode == "compiled":
            update = speedups.compiled_update(agent, losses, gamma, tau, target_entropy,
                                              (bs, obs, act), torch.device("cpu"))
        elif mode == "functional":
            update = speedups.functional_update(agent, losses, gamma, tau, target_entropy)
        else:
            optimizers = tuple(agent[k] for k in ("actor_optimizer", "q_optimizer",
                                                  "alpha_optimizer"))
            update = functools.partial(sac.sac_update, agent["actor"], agent["qf"],
                                       agent["qf_target"], agent["log_alpha"], optimizers,
                                       gamma=gamma, tau=tau, target_entropy=target_entropy)
    for i in range(30):
        update(*batches[i % 20])
    times = []
    for _ in range(5):
        start = time.process_time()
        for i in range(n):
            update(*batches[i % 20])
        times.append((time.process_time() - start) / n * 1e3)
    print(f"{root} {mode} obs {obs} act {act}: ms/update min {min(times):.2f} "
          f"median {sorted(times)[2]:.2f}")


if __name__ == "__main__":
    main()
