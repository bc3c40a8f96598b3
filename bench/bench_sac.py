"""Speed and memory of the SAC scripts: prints the figures quoted in docs/speed.md.

    .venv/bin/python bench/bench_sac.py --env-id h1hand-powerlift-v0

Times are process CPU seconds (the machine is shared; with one torch thread, CPU time is what
an idle machine's wall clock shows), medians over --repeats: one gradient update alone (the
script's, compiled with torch.compile unless --no-compile, then the other way; for comparison,
batched-matmul twin critics),
one env step alone, one actor forward; the training loop's cost per step after the start steps
(two runs of sac_standard.py as subprocesses, with and without --loop-steps more steps,
differenced); an evaluation round of 10 episodes; and the resident memory of a full
1M-transition replay buffer with 308-dim observations (bookshelf's size).
"""

import copy
import functools
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import psutil
import torch
import torch.nn as nn
import tyro

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import sac_standard  # noqa: E402
from sac_standard import (  # noqa: E402
    ReplayBuffer,
    TwinQ,
    actor_loss,
    alpha_loss,
    critic_loss,
    ends_without_bootstrap,
    eval_actions,
    make_agent,
    make_env,
    make_vector_env,
    physics_blow_up,
    sac_update,
    tanh_mu,
)
from sac_utils import cli  # noqa: E402
from sac_utils.eval_rounds import Round, eval_seeds, run_round  # noqa: E402
from sac_utils.speedups import compile_at_start, compiled_update, cuda_graph  # noqa: E402

# The timings' clock: process CPU seconds; the main block sets wall-clock seconds on --wall-clock.
clock = time.process_time


@dataclass
class Args:
    env_id: str = "h1hand-powerlift-v0"
    """the task to time"""
    batch_size: int = 64
    """batch size of the timed updates (the paper's)"""
    torch_threads: int = 1
    """torch CPU threads"""
    repeats: int = 5
    """repeats of each timing; medians are printed"""
    updates: int = 200
    """updates per timing repeat"""
    loop_steps: int = 3000
    """training-loop steps timed after the start steps (the whole loop, and its parts in place)"""
    eval_episodes: int = 10
    """episodes of the timed evaluation round"""
    compile: bool = True
    """time the update compiled (the scripts' default) first, then eager; --no-compile the
    reverse, and the other figures eager"""
    wall_clock: bool = False
    """time the in-process figures by wall clock instead of CPU time (to compare thread counts
    on an idle machine: CPU time adds up all threads)"""


class BatchedTwinQ(nn.Module):
    """The alternative the script's TwinQ was measured against: both critics in one network,
    every layer one batched matmul over a leading dimension of 2 (half the ops)."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...]):
        super().__init__()
        sizes = (obs_dim + action_dim, *hidden, 1)
        self.weights = nn.ParameterList(nn.Parameter(torch.empty(2, i, o))
                                        for i, o in zip(sizes, sizes[1:], strict=False))
        self.biases = nn.ParameterList(nn.Parameter(torch.empty(2, 1, o)) for o in sizes[1:])
        for w, b in zip(self.weights, self.biases, strict=True):  # nn.Linear's default init
            bound = w.shape[1] ** -0.5
            nn.init.uniform_(w, -bound, bound)
            nn.init.uniform_(b, -bound, bound)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """(batch, dim) inputs; (2, batch) out, as TwinQ's."""
        x = torch.cat([obs, action], -1).expand(2, -1, -1)
        last = len(self.weights) - 1  # indexed: a slice of a ParameterList does not compile
        for i in range(last):
            x = torch.relu(torch.baddbmm(self.biases[i], x, self.weights[i]))
        return torch.baddbmm(self.biases[last], x, self.weights[last]).squeeze(-1)


def median_time(fn, repeats: int, calls: int) -> float:
    """Median over repeats of the mean seconds per call (CPU or wall clock: --wall-clock)."""
    fn()  # warm-up (and compilation)
    times = []
    for _ in range(repeats):
        start = clock()
        for _ in range(calls):
            fn()
        times.append((clock() - start) / calls)
    return statistics.median(times)


def script_args(args: Args, **changes) -> sac_standard.Args:
    """sac_standard.py's arguments (its defaults: the paper's sizes) for this bench's task, batch
    size, threads and --compile; `changes` on top."""
    return replace(sac_standard.Args(env_id=args.env_id, seed=0), **{
        "batch_size": args.batch_size, "torch_threads": args.torch_threads,
        "compile": args.compile, **changes})


def script_agent(script: sac_standard.Args, obs_dim: int, action_space,
                 device: torch.device, critic_class=TwinQ) -> dict:
    """The script's make_agent; with another critic_class (BatchedTwinQ), its critics, their
    target and their optimizer swapped for that class's."""
    agent = make_agent(script, obs_dim, action_space, device)
    if critic_class is not TwinQ:
        qf = critic_class(obs_dim, action_space.shape[0], script.hidden_sizes).to(device)
        agent |= {"qf": qf, "qf_target": copy.deepcopy(qf),
                  "q_optimizer": torch.optim.Adam(qf.parameters(), lr=script.q_lr, fused=True,
                                                  capturable=device.type == "cuda")}
    return agent


def script_update(script: sac_standard.Args, agent: dict, rb: ReplayBuffer,
                  device: torch.device):
    """update(batch, noise) of this agent (script_agent), set up as sac_standard.py's main
    block does: compiled at start-up with --compile, a CUDA graph on CUDA with --cudagraphs."""
    target_entropy = -script.target_entropy_scale * rb.action_dim
    optimizers = (agent["actor_optimizer"], agent["q_optimizer"], agent["alpha_optimizer"])
    update = functools.partial(sac_update, agent["actor"], agent["qf"], agent["qf_target"],
                               agent["log_alpha"], optimizers, gamma=script.gamma,
                               tau=script.tau, target_entropy=target_entropy)
    restore = tuple(agent.values())
    if script.compile:
        update = compiled_update(agent, (critic_loss, actor_loss, alpha_loss), script.gamma,
                                 script.tau, target_entropy,
                                 (script.batch_size, rb.obs_dim, rb.action_dim), device)
    if device.type == "cuda" and script.cudagraphs:
        update = cuda_graph(update, restore)
    return update


def script_act(script: sac_standard.Args, actor, obs_dim: int, action_dim: int,
               device: torch.device):
    """act(obs, noise), a sampled action, as sac_standard.py's main block builds it."""
    act = torch.no_grad()(lambda obs, noise: actor.squash(*actor(obs), noise)[0])
    if script.compile:
        act = compile_at_start(act, (torch.zeros((1, obs_dim), device=device),
                                     torch.zeros((1, action_dim), device=device)))
    if device.type == "cuda" and script.cudagraphs:
        act = cuda_graph(act)
    return act


def training_step(script: sac_standard.Args, rb: ReplayBuffer, update, device: torch.device):
    """What the training loop does per step to learn, as a function of nothing: draw a batch and
    the policy noise, and update."""
    noise_shape = (2, script.batch_size, rb.action_dim)  # the next action's and the action's
    return lambda: update(rb.sample(script.batch_size, device),
                          torch.randn(noise_shape, device=device))


def random_buffer(size: int, obs_dim: int, action_dim: int,
                  device: torch.device) -> ReplayBuffer:
    """A full buffer of random transitions."""
    rb = ReplayBuffer(size, obs_dim, action_dim, device)
    rng = np.random.default_rng(0)
    for _ in range(size):
        rb.add(rng.normal(size=obs_dim), rng.uniform(-1, 1, action_dim), rng.normal(), False,
               rng.normal(size=obs_dim))
    return rb


def time_update(args: Args, env, critic_class=TwinQ, compiled: bool = True) -> float:
    """Seconds per training step's learning, as the loop does it: batch sampling, policy noise and
    the script's update (compiled or eager)."""
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    cpu = torch.device("cpu")
    script = script_args(args, compile=compiled)
    rb = random_buffer(20_000, obs_dim, action_dim, cpu)
    update = script_update(script, script_agent(script, obs_dim, env.action_space, cpu,
                                                critic_class), rb, cpu)
    return median_time(training_step(script, rb, update, cpu), args.repeats, args.updates)


def time_env_step(env, steps: int, repeats: int) -> tuple[float, float]:
    """Seconds per env step with random actions (resets included), and mean episode length."""
    env.reset(seed=0)
    env.action_space.seed(0)
    lengths, length = [], 0

    def step():
        nonlocal length
        length += 1
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            lengths.append(length)
            length = 0
            env.reset()

    return median_time(step, repeats, steps), (np.mean(lengths) if lengths else float(length))


def time_actor_forward(args: Args, env, repeats: int) -> float:
    """Seconds of one evaluation action of the script's untrained actor on one observation:
    tanh(mu) (sac_standard.tanh_mu), scaled to the env's bounds."""
    script = script_args(args)
    actor = script_agent(script, env.observation_space.shape[0], env.action_space,
                         torch.device("cpu"))["actor"]
    obs = torch.as_tensor(env.observation_space.sample(), dtype=torch.float32)[None]

    def forward():
        with torch.no_grad():
            actor.scale(tanh_mu(*actor(obs), script.mode_solver))[0].numpy()

    return median_time(forward, repeats, 500)


def script_cpu_seconds(args: Args, total_timesteps: int, learning_starts: int) -> float:
    """CPU seconds of one whole sac_standard.py run (no evaluation, no checkpoint)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([sys.executable, str(ROOT / "sac_standard.py"), "--env-id", args.env_id,
                        "--total-timesteps", str(total_timesteps), "--learning-starts",
                        str(learning_starts), "--eval-interval", str(10 * total_timesteps),
                        "--checkpoint-interval", "0", "--torch-threads", str(args.torch_threads),
                        "--batch-size", str(args.batch_size),
                        "--compile" if args.compile else "--no-compile",
                        "--output-dir", out, "--run-name", "bench"], check=True,
                       capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def loop_seconds_per_step(args: Args) -> float:
    """CPU seconds per training-loop step after the start steps: a run with --loop-steps more
    steps minus a run that stops one step after learning starts, repeated; median. A first,
    untimed short run fills torch.compile's cache, so that neither timed run compiles cold
    (the first would otherwise pay for both)."""
    start = 1000
    script_cpu_seconds(args, start + 1, start)
    return statistics.median(
        (script_cpu_seconds(args, start + args.loop_steps, start)
         - script_cpu_seconds(args, start + 1, start)) / (args.loop_steps - 1)
        for _ in range(max(1, args.repeats // 2)))


def time_loop_parts(args: Args, start: int = 1000) -> dict[str, float]:
    """Seconds per step of each part of the training loop, timed in place (interleaved as in
    sac_standard.py's loop, so each part pays for the caches the others evict): its vector env
    of one (in-process), its act, its buffer, its update; not its logging and bookkeeping.
    --loop-steps steps after `start` random ones."""
    cpu, steps = torch.device("cpu"), args.loop_steps
    script = script_args(args)
    torch.manual_seed(script.seed)
    space = make_env(args.env_id).action_space
    space.seed(script.seed)
    envs = make_vector_env(args.env_id)
    obs_dim, action_dim = envs.single_observation_space.shape[0], space.shape[0]
    agent = script_agent(script, obs_dim, space, cpu)
    rb = ReplayBuffer(script.buffer_size, obs_dim, action_dim, cpu)
    act = script_act(script, agent["actor"], obs_dim, action_dim, cpu)
    update = script_update(script, agent, rb, cpu)
    noise_shape = (2, script.batch_size, action_dim)
    parts = dict.fromkeys(("act", "env step", "buffer add", "batch sample", "update"), 0.0)
    obs, _ = envs.reset(seed=script.seed)
    for step in range(start + steps):
        t0 = clock()
        if step < start:
            action = space.sample()[None]
        else:
            action = act(torch.as_tensor(obs, dtype=torch.float32, device=cpu),
                         torch.randn((1, action_dim), device=cpu)).cpu().numpy()
            cli.check_finite(action, "action")
        t1 = clock()
        next_obs, reward, terminated, truncated, info = envs.step(action)
        t2 = clock()
        episode_end = bool(terminated[0] or truncated[0])
        final_obs = info["final_obs"][0] if episode_end else next_obs[0]
        if not physics_blow_up(info, episode_end):
            rb.add(obs[0], action[0], reward[0],
                   ends_without_bootstrap(terminated, truncated)[0], final_obs)
        obs = next_obs
        t3 = clock()
        if step < start:
            continue
        batch = rb.sample(script.batch_size, cpu)
        noise = torch.randn(noise_shape, device=cpu)
        t4 = clock()
        update(batch, noise)
        t5 = clock()
        for name, seconds in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4),
                                 strict=True):
            parts[name] += seconds
    envs.close()
    return {name: total / steps for name, total in parts.items()}


def time_eval_round(args: Args, env, episodes: int) -> tuple[float, float]:
    """Seconds of one evaluation round with tanh(mu) of the script's untrained actor, and its
    steps."""
    script = script_args(args)
    actor = script_agent(script, env.observation_space.shape[0], env.action_space,
                         torch.device("cpu"))["actor"]
    start = clock()
    result = run_round(Round(env.spec.id, eval_seeds(script.seed, 1, episodes),
                             eval_actions(script), actor, mode_solver=script.mode_solver))
    return clock() - start, sum(result[""]["lengths"])


def replay_buffer_memory_gb() -> float:
    """Resident memory added by a full 1M x 308-dim buffer (61-dim actions), in GB."""
    process = psutil.Process()
    before = process.memory_info().rss
    rb = ReplayBuffer(1_000_000, 308, 61, torch.device("cpu"))
    for name in ReplayBuffer.ARRAYS:
        getattr(rb, name)[:] = 1  # touch every page
    return (process.memory_info().rss - before) / 1e9


if __name__ == "__main__":
    args = tyro.cli(Args)
    if args.wall_clock:
        clock = time.perf_counter
    torch.set_num_threads(args.torch_threads)
    env = make_env(args.env_id)
    obs_dim, action_dim = env.observation_space.shape[0], env.action_space.shape[0]
    print(f"{args.env_id}: obs {obs_dim}, actions {action_dim}, batch {args.batch_size}, "
          f"torch threads {args.torch_threads}, torch {torch.__version__}")
    update = time_update(args, env, compiled=args.compile)
    print(f"update ({'compiled' if args.compile else 'eager'}, as the scripts run it):"
          f"{'':5s}{update * 1e3:6.2f} ms")
    print(f"  {'eager' if args.compile else 'compiled'} (--{'no-' * args.compile}compile):"
          f"{'':17s}{time_update(args, env, compiled=not args.compile) * 1e3:6.2f} ms")
    batched = time_update(args, env, BatchedTwinQ, compiled=args.compile)
    print(f"  with batched-matmul twin critics:   {batched * 1e3:6.2f} ms")
    env_step, episode_length = time_env_step(env, 1000, args.repeats)
    actor_forward = time_actor_forward(args, env, args.repeats)
    print(f"env step:                             {env_step * 1e3:6.2f} ms "
          f"(random-action episodes of {episode_length:.0f} steps)")
    print(f"actor forward (1 obs):                {actor_forward * 1e3:6.2f} ms")
    loop = loop_seconds_per_step(args)
    print(f"training loop:                        {loop * 1e3:6.2f} ms/step "
          f"({1 / loop:.0f} steps/s); "
          f"update + env step = {(update + env_step) * 1e3:.2f} ms: loop overhead "
          f"{100 * (loop / (update + env_step) - 1):+.0f}%")
    parts = time_loop_parts(args)
    print("  in place: " + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in parts.items())
          + f" (sum {sum(parts.values()) * 1e3:.2f} ms)")
    seconds, steps = time_eval_round(args, make_env(args.env_id), args.eval_episodes)
    predicted = steps * (env_step + actor_forward)
    print(f"eval round: {args.eval_episodes} episodes, {steps} steps in {seconds:.2f} s CPU; "
          f"steps x (env step + actor forward) = {predicted:.2f} s "
          f"({100 * (seconds / predicted - 1):+.0f}%)")
    print(f"replay buffer 1M x 308-dim obs + 61-dim actions: {replay_buffer_memory_gb():.2f} GB "
          "resident")
