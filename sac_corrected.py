"""Soft Actor-Critic, corrected: evaluates with the mode of the tanh-squashed Gaussian policy.

Defaults are the paper's protocol (its Tables I and II) and HumanoidBench's SAC; the run folder
is described in docs/scripts.md. Training is sac_standard.py's, step for step: `diff` the two files
to see the correction. Each evaluation round also acts with tanh(mu) from the same starts (paired)
and logs how far the mode is from it: the paper's distribution shift, measured during training.
"""

import copy
import functools
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from torch.func import functional_call

import humanoid_envs  # noqa: F401  (registers the h1hand-*-v0 tasks)
from mode_search import mode_action

# Not the algorithm (docs/scripts.md), from sac_utils/: cli (bad input), run_folder (RunFolder: the
# folder, logs, evaluation rounds, checkpoints; with checkpoints), speedups (compile, CUDA graphs).
from sac_utils import cli
from sac_utils.checkpoints import EpisodeRecord
from sac_utils.run_folder import RunFolder, StopRequest
from sac_utils.speedups import ReLU, adam_state, adam_step, compile_at_start, cuda_graph, grad

ALGORITHM = "corrected"


@dataclass
class Args:
    env_id: str = "h1hand-stand-v0"
    """the environment id of the task (any gymnasium env with a Box action space)"""
    seed: int = 0
    """seed of the experiment (the paper uses seeds 0-4)"""
    total_timesteps: int = 10_000_000
    """total environment steps of the run"""
    buffer_size: int = 1_000_000
    """the replay buffer size (observations stored, about one per transition)"""
    gamma: float = 0.99
    """the discount factor gamma"""
    tau: float = 0.005
    """target network smoothing coefficient"""
    batch_size: int = 64
    """the batch size of each gradient update"""
    learning_starts: int = 10_000
    """steps of uniform random actions before the first gradient update"""
    policy_lr: float = 3e-4
    """the learning rate of the actor's optimizer"""
    q_lr: float = 3e-4
    """the learning rate of the twin critics' optimizer"""
    alpha_lr: float = 3e-4
    """the learning rate of the temperature's optimizer"""
    alpha_init: float = 1.0
    """the initial entropy temperature alpha (learned)"""
    target_entropy_scale: float = 0.5
    """target entropy = -target_entropy_scale * |A| (HumanoidBench: -|A|/2)"""
    hidden_sizes: tuple[int, ...] = (256, 256)
    """hidden layer widths of the actor and of each critic"""
    log_std_min: float = -10.0
    """lower clip of the actor's log sigma (clipped, as HumanoidBench; not tanh-rescaled)"""
    log_std_max: float = 2.0
    """upper clip of the actor's log sigma"""
    eval_interval: int = 10_000
    """evaluate every this many environment steps"""
    eval_episodes: int = 10
    """episodes per evaluation round"""
    eval_reset_noise: float | None = None
    """h1hand tasks: uniform noise of this half-width on qpos at each evaluation reset (default:
    the task's own, the paper's protocol; 0.01 is HumanoidBench's, off on bookshelf and cube)"""
    eval_selectors: tuple[Literal["mode", "tanh_mu", "mean", "q_best"], ...] = ()
    """more evaluation actions, paired with the script's own (the same starts; eval_rounds.py):
    "mean" (E[tanh(u)]), "q_best" (the critic's pick), "mode", "tanh_mu"; eval.csv columns
    <name>_*"""
    mode_solver: Literal["exact", "grid"] = "exact"
    """how to find the mode: "exact" (iterative solve) or "grid" (the paper's Algorithm 1)"""
    eval_workers: int | None = None
    """processes running evaluation rounds beside training (default: the free cores; 0: inline)"""
    log_interval: int = 1000
    """write a train.csv / TensorBoard row every this many steps"""
    print_interval: int = 10_000
    """print a progress line every this many steps"""
    output_dir: str = "runs"
    """the folder that holds run folders"""
    run_name: str | None = None
    """the run folder's name (default: {env_id}__{algorithm}__seed{seed}__{date-time})"""
    resume: str | None = None
    """continue the run in this run folder from its checkpoint, with its stored arguments"""
    checkpoint_interval: int = 100_000
    """checkpoint every this many steps (0: off)"""
    snapshot_interval: int = 0
    """keep the actor and critic every this many steps in snapshots/ for evaluate.py (0: off)"""
    cuda: bool = True
    """use a CUDA GPU if there is one"""
    compile: bool = True
    """torch.compile the update and the acting at start-up (~1.6x faster on a CPU; needs g++)"""
    cudagraphs: bool = True
    """on CUDA: replay the update and the training action as CUDA graphs"""
    gpu_buffer: bool = True
    """on CUDA: keep the replay buffer in GPU memory (1.2 GB per 1M h1hand observations)"""
    torch_threads: int = 1
    """torch CPU threads (1 is fastest for batch 64 on small CPUs; see docs/speed.md)"""
    capture_video: bool = False
    """write a video of the first episode of each evaluation round into the run folder"""
    track: bool = False
    """log the run to Weights & Biases (config, every TensorBoard scalar, evaluation videos)"""
    wandb_project_name: str = "corrected-sac"
    """the W&B project"""
    wandb_entity: str | None = None
    """the W&B entity (team or user; default: yours)"""
    wandb_group: str | None = None
    """the W&B group (sweep.py sets {env_id}__{algorithm})"""


def mode(mu: torch.Tensor, log_std: torch.Tensor, solver: str) -> torch.Tensor:
    """The action this script evaluates with, in (-1, 1)^A before the env's scaling: the mode of
    the tanh-squashed Gaussian, its most probable action (mode_search.py), not tanh(mu)."""
    return mode_action(mu, log_std, solver)


def eval_actions(args: Args) -> dict:
    """Evaluation actions by eval.csv column prefix: this script's own (unprefixed columns),
    tanh(mu) paired with it (the same start states), and the --eval-selectors (eval_rounds.py)."""
    return {"": mode, "tanh_mu_": "tanh_mu", **{f"{s}_": s for s in args.eval_selectors}}


def make_env(env_id: str, render: bool = False) -> gym.Env:
    """The gymnasium env; an unknown id or spaces SAC cannot use end the run in one line."""
    render_mode = {"render_mode": "rgb_array"} if render else {}
    env = gym.make(cli.registered_env_id(env_id), **render_mode)
    return cli.check_spaces(env, env_id)


def make_vector_env(env_id: str) -> gym.vector.VectorEnv:
    """The training env, a vector env of one (CleanRL's way) that resets in the step that ends an
    episode, its final observation in info["final_obs"]."""
    return gym.vector.SyncVectorEnv([lambda: EpisodeRecord(gym.make(env_id))],
                                    autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)


class Linear(nn.Module):
    """nn.Linear with its weight stored (in, out), not (out, in): no transpose in the matmul,
    whose forward and backward are then ~20% cheaper on a CPU (bench/bench_sac.py)."""

    def __init__(self, in_features: int, out_features: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(in_features, out_features))
        self.bias = nn.Parameter(torch.zeros(out_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # bmm, not addmm: compiled, inductor sums a one-output layer's gradient in another order
        # for mm, and runs made before issue 37 would no longer be reproduced bit for bit.
        return torch.baddbmm(self.bias, x[None], self.weight[None])[0]


def mlp(sizes: tuple[int, ...]) -> nn.Sequential:
    """An MLP with ReLU (speedups.ReLU: torch.relu, faster compiled) between layers, not after."""
    layers = [m for i, o in zip(sizes, sizes[1:], strict=False) for m in (Linear(i, o), ReLU())]
    return nn.Sequential(*layers[:-1])


def init_glorot(module: nn.Module, generator: torch.Generator | None) -> None:
    """Glorot-uniform weights on every layer, output heads included (Linear's biases start at
    zero): HumanoidBench's jaxrl_m networks (flax's variance_scaling(1, "fan_avg", "uniform")),
    not PyTorch's default."""
    for layer in module.modules():
        if isinstance(layer, Linear):
            nn.init.xavier_uniform_(layer.weight, generator=generator)


class Actor(nn.Module):
    def __init__(self, obs_dim: int, hidden: tuple[int, ...], action_space: gym.spaces.Box,
                 log_std_min: float, log_std_max: float, generator: torch.Generator | None = None):
        super().__init__()
        sizes, action_dim = (obs_dim, *hidden), int(np.prod(action_space.shape))
        self.trunk = nn.Sequential(*mlp(sizes), ReLU())
        self.fc_mean = Linear(sizes[-1], action_dim)
        self.fc_logstd = Linear(sizes[-1], action_dim)
        low, high = (torch.as_tensor(b, dtype=torch.float32) for b in (action_space.low,
                                                                      action_space.high))
        self.register_buffer("action_scale", (high - low) / 2)
        self.register_buffer("action_bias", (high + low) / 2)
        self.log_std_min, self.log_std_max = log_std_min, log_std_max
        init_glorot(self, generator)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """mu and log sigma of the Gaussian before the tanh squashing, (batch, A)."""
        h = self.trunk(obs)
        return self.fc_mean(h), self.fc_logstd(h).clamp(self.log_std_min, self.log_std_max)

    def squash(self, mu: torch.Tensor, log_std: torch.Tensor,
               noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The sample scale * tanh(u) + bias, u = mu + sigma * noise, and its log-density."""
        u = mu + noise * log_std.exp()
        # log N(u) - log|d tanh(u)/du| - log(scale), with the stable form of log(1 - tanh(u)^2).
        log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * np.log(2 * np.pi)
                    - 2 * (np.log(2) - u - nn.functional.softplus(-2 * u))
                    - self.action_scale.log())
        return self.scale(torch.tanh(u)), log_prob.sum(-1)

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        """Maps a squashed action in (-1, 1)^A to the env's bounds."""
        return y * self.action_scale + self.action_bias


class TwinQ(nn.Module):
    """The twin critics Q1 and Q2, two MLPs (one batched matmul measured no faster on a CPU)."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...],
                 generator: torch.Generator | None = None):
        super().__init__()
        self.qf1, self.qf2 = (mlp((obs_dim + action_dim, *hidden, 1)) for _ in range(2))
        init_glorot(self, generator)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q1 and Q2 of each (obs, action), shape (2, batch)."""
        x = torch.cat([obs, action], -1)
        return torch.stack([self.qf1(x), self.qf2(x)]).squeeze(-1)


class ReplayBuffer:
    """The replay buffer, float32 tensors on `device`, each observation stored once: slot i's
    next observation is in slot i + 1. An episode's last transition is followed by a slot that
    holds only its final observation (never sampled): a truncated episode bootstraps from its
    true final observation, and no transition spans a reset."""

    DRAWS_PER_ROW = 16  # slots drawn per batch row (see sample)
    ARRAYS = ("obs", "actions", "rewards", "terminated", "valid")  # what a checkpoint keeps

    def __init__(self, size: int, obs_dim: int, action_dim: int, device: torch.device):
        self.size, self.obs_dim, self.action_dim = size, obs_dim, action_dim
        self.ptr, self.filled = 0, 0
        self.obs = torch.zeros((size, obs_dim), device=device)
        self.actions = torch.zeros((size, action_dim), device=device)
        self.rewards = torch.zeros(size, device=device)
        self.terminated = torch.zeros(size, device=device)
        self.valid = torch.zeros(size, dtype=torch.bool, device=device)  # holds a transition

    def add(self, obs: np.ndarray, action: np.ndarray, reward: float, terminated: bool,
            next_obs: np.ndarray, episode_end: bool, blow_up: bool = False) -> None:
        """One transition, in one copy to the buffer's device. A `blow_up` one (a physics
        blow-up, reporting the previous observation) is not stored: its episode ends at the slot
        of that observation, the last it reached soundly."""
        i, j = self.ptr, (self.ptr + 1) % self.size
        if blow_up:  # rare
            self.ptr = j if self.valid[(i - 1) % self.size] else i
            return
        packed = torch.as_tensor(np.concatenate([obs, action, [reward, terminated], next_obs],
                                                dtype=np.float32)).to(self.obs.device)
        o, a, r, t, n = packed.split([self.obs_dim, self.action_dim, 1, 1, self.obs_dim])
        self.obs[i], self.actions[i], self.rewards[i], self.terminated[i] = o, a, r[0], t[0]
        self.valid[i] = True
        self.obs[j], self.valid[j] = n, False
        self.ptr = (j + 1) % self.size if episode_end else j
        self.filled = self.size if j == 0 else max(self.filled, j + 1)

    def sample(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """Uniform over the stored transitions: obs, actions, rewards, next_obs, 1 - terminated.
        Each row keeps the first of DRAWS_PER_ROW random slots that holds a transition (no
        data-dependent loop, no host sync on a GPU); if none does (probability (episodes /
        slots)^16), the slot before, that episode's last transition."""
        slots = torch.randint(2**62, (self.DRAWS_PER_ROW, batch_size),
                              device=self.obs.device) % self.filled
        first = self.valid[slots].byte().argmax(0)  # argmax returns the first maximum
        idx = slots.gather(0, first[None])[0]
        idx = torch.where(self.valid[idx], idx, (idx - 1) % self.size)
        batch = (self.obs[idx], self.actions[idx], self.rewards[idx],
                 self.obs[(idx + 1) % self.size], 1 - self.terminated[idx])
        return tuple(t.to(device, non_blocking=True) for t in batch)

    def zero_batch(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """A batch shaped as sample()'s, all zeros (for a first call that must not learn)."""
        return tuple(torch.zeros((batch_size, *shape), device=device) for shape in (
            (self.obs_dim,), (self.action_dim,), (), (self.obs_dim,), ()))


def sac_losses(params: tuple[dict, dict, torch.Tensor], qf_target_params: dict,
               batch: tuple[torch.Tensor, ...], noise: torch.Tensor, actor: Actor, qf: TwinQ,
               gamma: float, target_entropy: float) -> tuple[torch.Tensor, tuple]:
    """The critic, actor and temperature losses, summed: the critics' parameters get the critic
    loss's gradient (the actor loss sees them detached), the actor's the actor loss's, log alpha
    the temperature loss's. noise: (2, batch, A). Also returns what train.csv logs."""
    # functional_call runs an nn.Module on the parameters given here, which grad differentiates.
    actor_params, qf_params, log_alpha = params

    def policy(obs: torch.Tensor, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return actor.squash(*functional_call(actor, actor_params, obs), noise)

    def q(params: dict, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return functional_call(qf, params, (obs, action))

    b_obs, b_actions, b_rewards, b_next_obs, b_not_done = batch
    alpha = log_alpha.exp().detach()
    with torch.no_grad():
        next_actions, next_log_pi = policy(b_next_obs, noise[0])
        min_qf_next = q(qf_target_params, b_next_obs, next_actions).min(0).values
        next_q_value = b_rewards + b_not_done * gamma * (min_qf_next - alpha * next_log_pi)
    qf_values = q(qf_params, b_obs, b_actions)
    qf_losses = (qf_values - next_q_value).pow(2).mean(-1)
    pi, log_pi = policy(b_obs, noise[1])
    frozen_qf = {name: p.detach() for name, p in qf_params.items()}
    actor_loss = (alpha * log_pi - q(frozen_qf, b_obs, pi).min(0).values).mean()
    alpha_loss = -(log_alpha.exp() * (log_pi.detach() + target_entropy)).mean()
    total = qf_losses.sum() + actor_loss + alpha_loss
    return total, (qf_losses, qf_values, actor_loss, alpha, alpha_loss, log_pi)


@torch.no_grad()  # grad turns gradients on for the losses alone
def sac_update(tensors: dict, batch: tuple[torch.Tensor, ...], noise: torch.Tensor,
               actor: Actor, qf: TwinQ, gamma: float, tau: float,
               target_entropy: float) -> tuple[torch.Tensor, ...]:
    """One gradient step of the critics, actor and temperature, and the critics' Polyak-averaged
    targets, in place on `tensors` (agent_tensors): tensors in, so that it
    compiles whole, once. As HumanoidBench's jaxrl_m, all three losses use the parameters from
    before this update, and the target moves towards that critic. Returns train.csv's logs."""
    params = (tensors["actor"], tensors["qf"], tensors["log_alpha"])
    # grad: torch.func.grad's (sac_utils/speedups.py: torch.autograd's when not compiled, the same
    # numbers).
    grads, logs = grad(sac_losses)(params, tensors["qf_target"], batch, noise, actor, qf, gamma,
                                   target_entropy)
    torch._foreach_lerp_(list(tensors["qf_target"].values()), list(tensors["qf"].values()), tau)
    for p, g, state in zip(params, grads, tensors["adam"], strict=True):
        if isinstance(p, dict):
            adam_step(list(p.values()), list(g.values()), state)
        else:
            adam_step([p], [g], state)
    return logs


def make_agent(args: Args, obs_dim: int, action_space: gym.spaces.Box,
               device: torch.device) -> dict:
    """The actor, twin critics and their target, log alpha and their Adam optimizers, by their
    names in checkpoint.pt. The initial weights come from a generator of their own, so torch's
    (the actions and the batches) starts from the seed alone."""
    generator = torch.Generator().manual_seed(args.seed)
    actor = Actor(obs_dim, args.hidden_sizes, action_space, args.log_std_min, args.log_std_max,
                  generator).to(device)
    qf = TwinQ(obs_dim, action_space.shape[0], args.hidden_sizes, generator).to(device)
    log_alpha = torch.tensor(float(np.log(args.alpha_init)), device=device, requires_grad=True)
    # The optimizers hold Adam's state (for checkpoints); sac_update steps it. fused: a loaded
    # state_dict puts the step counts on the parameters' device, as a CUDA graph needs.
    adam = functools.partial(torch.optim.Adam, fused=True, capturable=device.type == "cuda")
    return {"actor": actor, "qf": qf, "qf_target": copy.deepcopy(qf), "log_alpha": log_alpha,
            "actor_optimizer": adam(actor.parameters(), lr=args.policy_lr),
            "q_optimizer": adam(qf.parameters(), lr=args.q_lr),
            "alpha_optimizer": adam([log_alpha], lr=args.alpha_lr)}


def agent_tensors(actor: Actor, qf: TwinQ, qf_target: TwinQ, log_alpha: torch.Tensor,
                  actor_optimizer: torch.optim.Optimizer, q_optimizer: torch.optim.Optimizer,
                  alpha_optimizer: torch.optim.Optimizer) -> dict:
    """What sac_update reads and changes, make_agent's own tensors (so an update changes them in
    place; call this after a checkpoint's load, which replaces the optimizers' tensors)."""
    return {"actor": dict(actor.named_parameters()), "qf": dict(qf.named_parameters()),
            "qf_target": dict(qf_target.named_parameters()), "log_alpha": log_alpha,
            "adam": [adam_state(o) for o in (actor_optimizer, q_optimizer, alpha_optimizer)]}


def ends_without_bootstrap(terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
    """Whether a transition's target drops the next state's value (HumanoidBench's mask is
    `not terminated or truncated`)."""
    return terminated & ~truncated


def physics_blow_up(info: dict, episode_end: bool) -> bool:
    """Whether the env's last step was a physics blow-up (h1hand's info["physics_unstable"])."""
    final = info.get("final_info", {})
    return episode_end and bool(final.get("physics_unstable", [False])[0])


if __name__ == "__main__":
    args = cli.parse_args(Args, ALGORITHM, eval_actions)
    stop = StopRequest()  # from the start: a signal during setup also ends in code 3
    run = RunFolder(args, ALGORITHM, Path(__file__).name, eval_actions(args))
    torch.set_num_threads(args.torch_threads)
    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002
    torch.manual_seed(args.seed)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    print(f"device: {device}", flush=True)

    env = make_env(args.env_id)  # checks the id and the spaces
    cli.check_reset_noise(env, args.env_id, args.eval_reset_noise)
    action_space = env.action_space  # draws the random start actions
    action_space.seed(args.seed)
    envs = make_vector_env(args.env_id)
    obs_dim, action_dim = envs.single_observation_space.shape[0], action_space.shape[0]

    agent = make_agent(args, obs_dim, action_space, device)
    actor, qf = agent["actor"], agent["qf"]
    target_entropy = -args.target_entropy_scale * action_dim
    rb = ReplayBuffer(args.buffer_size, obs_dim, action_dim,
                      device if args.gpu_buffer else torch.device("cpu"))
    global_step, obs = run.open(agent, rb, action_space, envs, device)  # fresh or resumed

    # Acting: a sampled action from the observation and the noise, (1, obs) -> (1, A).
    act = torch.no_grad()(lambda obs, noise: actor.squash(*actor(obs), noise)[0])
    tensors = agent_tensors(**agent)
    update = functools.partial(sac_update, actor=actor, qf=qf, gamma=args.gamma, tau=args.tau,
                               target_entropy=target_entropy)
    noise_shape = (2, args.batch_size, action_dim)  # the next action's and the action's
    # Speed (sac_utils/speedups.py): both compiled whole at start-up and, on a GPU, replayed as CUDA
    # graphs; the warm-up calls leave the agent as it was.
    if args.compile:
        act = compile_at_start(act, (torch.zeros((1, obs_dim), device=device),
                                     torch.zeros((1, action_dim), device=device)), (), "acting")
        update = compile_at_start(update, (tensors, rb.zero_batch(args.batch_size, device),
                                           torch.zeros(noise_shape, device=device)),
                                  tuple(agent.values()), "the update")
    update = functools.partial(update, tensors)  # the agent's tensors change in place
    if device.type == "cuda" and args.cudagraphs:
        act, update = cuda_graph(act), cuda_graph(update, tuple(agent.values()))

    losses = None
    while global_step < args.total_timesteps:
        if global_step < args.learning_starts:
            action = action_space.sample()[None]  # (1, A): the vector env's one env
        else:
            action = act(torch.as_tensor(obs, dtype=torch.float32, device=device),
                         torch.randn((1, action_dim), device=device)).cpu().numpy()
            cli.check_finite(action, "action")
        next_obs, reward, terminated, truncated, info = envs.step(action)
        global_step += 1
        episode_end = bool(terminated[0] or truncated[0])
        # An ended episode's env has already reset: its final observation is in info.
        final_obs = info["final_obs"][0] if episode_end else next_obs[0]
        rb.add(obs[0], action[0], reward[0], ends_without_bootstrap(terminated, truncated)[0],
               final_obs, episode_end, physics_blow_up(info, episode_end))
        obs = next_obs
        run.count_step(reward[0], episode_end)

        if global_step >= run.updates_from:  # --learning-starts (later after a restart)
            batch = rb.sample(args.batch_size, device)
            losses = update(batch, torch.randn(noise_shape, device=device))

        if global_step % args.log_interval == 0:
            run.log_train(global_step, losses)
        if global_step % args.eval_interval == 0:
            run.evaluate(global_step, actor, qf)  # eval_actions(args), in a worker process
        run.poll_evaluations()
        if global_step % args.print_interval == 0:
            run.print_progress(global_step)
        if args.snapshot_interval > 0 and global_step % args.snapshot_interval == 0:
            run.save_snapshot(global_step, actor, qf, agent["log_alpha"])
        if stop.requested or (args.checkpoint_interval > 0
                              and global_step % args.checkpoint_interval == 0):
            run.checkpoint(global_step, agent, rb, action_space, envs, stop.requested)
            if stop.requested:
                run.stop(global_step)

    run.finish(global_step, actor, qf)
