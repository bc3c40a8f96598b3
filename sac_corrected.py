"""Soft Actor-Critic, corrected: evaluates with the mode of the tanh-squashed Gaussian policy.

Defaults: the paper's protocol (Tables I, II) and HumanoidBench's SAC; run folder: docs/scripts.md.
Training is sac_standard.py's: `diff` the two files to see the correction. Each evaluation round
also acts with tanh(mu) from the same starts and logs the mode's distance from it (the shift).
"""

import copy
import functools
import random
from dataclasses import dataclass
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

import humanoid_envs  # noqa: F401  (registers the h1hand-*-v0 tasks)
from mode_search import mode_action

# Not the algorithm (docs/scripts.md): bad input, the run folder, torch.compile and CUDA graphs.
from sac_utils import checkpoints, cli, run_folder, speedups

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
    """the replay buffer size, in transitions"""
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
    """lower clip of the actor's log sigma (HumanoidBench clips; CleanRL tanh-rescales)"""
    log_std_max: float = 2.0
    """upper clip of the actor's log sigma"""
    eval_interval: int = 10_000
    """evaluate every this many environment steps"""
    eval_episodes: int = 10
    """episodes per evaluation round"""
    eval_reset_noise: float | None = None
    """h1hand tasks: half-width of the uniform qpos noise at evaluation resets (None: the task's)"""
    eval_selectors: tuple[Literal["mode", "tanh_mu", "mean", "q_best"], ...] = ()
    """more evaluation actions from the same starts (eval_rounds.py); eval.csv columns <name>_*"""
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
    """torch.compile the acting and the update at start-up (sac_utils/speedups.py; needs g++)"""
    cudagraphs: bool = True
    """on CUDA: replay the update and the training action as CUDA graphs"""
    gpu_buffer: bool = True
    """on CUDA: keep the replay buffer in GPU memory (1.6-2.7 GB per 1M h1hand transitions)"""
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
    """The evaluation action, in (-1, 1)^A before the env's scaling: the squashed policy's mode."""
    return mode_action(mu, log_std, solver)


def eval_actions(args: Args) -> dict:
    """Evaluation actions by eval.csv column prefix: its own (""), tanh(mu), --eval-selectors."""
    return {"": mode, "tanh_mu_": "tanh_mu", **{f"{s}_": s for s in args.eval_selectors}}


def make_env(env_id: str) -> gym.Env:
    """The gymnasium env; an unknown id or spaces SAC cannot use end the run in one line."""
    return cli.check_spaces(gym.make(cli.registered_env_id(env_id)), env_id)


def make_vector_env(env_id: str) -> gym.vector.VectorEnv:
    """A vector env of one (CleanRL's): it resets in the step that ends an episode."""
    return gym.vector.SyncVectorEnv([lambda: checkpoints.EpisodeRecord(gym.make(env_id))],
                                    autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)


def mlp(sizes: tuple[int, ...]) -> nn.Sequential:
    """Linear layers with a ReLU between each two, none after the last."""
    pairs = zip(sizes, sizes[1:], strict=False)
    layers = [m for i, o in pairs for m in (nn.Linear(i, o), nn.ReLU())]
    return nn.Sequential(*layers[:-1])


def init_glorot(module: nn.Module, generator: torch.Generator | None) -> None:
    """Glorot-uniform weights, zero biases, heads included: HumanoidBench's, not PyTorch's."""
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            nn.init.xavier_uniform_(layer.weight, generator=generator)
            nn.init.zeros_(layer.bias)


class Actor(nn.Module):
    def __init__(self, obs_dim: int, hidden: tuple[int, ...], action_space: gym.spaces.Box,
                 log_std_min: float, log_std_max: float, generator: torch.Generator | None = None):
        super().__init__()
        sizes, action_dim = (obs_dim, *hidden), int(np.prod(action_space.shape))
        self.trunk = nn.Sequential(*mlp(sizes), nn.ReLU())
        self.fc_mean = nn.Linear(sizes[-1], action_dim)
        self.fc_logstd = nn.Linear(sizes[-1], action_dim)
        low = torch.as_tensor(action_space.low, dtype=torch.float32)
        high = torch.as_tensor(action_space.high, dtype=torch.float32)
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
        """scale * tanh(mu + sigma * noise) + bias and its log-density (noise drawn outside)."""
        u = mu + noise * log_std.exp()
        # log N(u) - log|d tanh(u)/du| - log(scale), with the stable form of log(1 - tanh(u)^2).
        log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * np.log(2 * np.pi)
                    - 2 * (np.log(2) - u - F.softplus(-2 * u)) - self.action_scale.log())
        return self.scale(torch.tanh(u)), log_prob.sum(-1)

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        """Maps a squashed action in (-1, 1)^A to the env's bounds."""
        return y * self.action_scale + self.action_bias


class TwinQ(nn.Module):
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
    """CleanRL's: a ring of `size` transitions as float32 tensors on `device`."""

    ARRAYS = ("obs", "actions", "rewards", "next_obs", "terminated")  # what a checkpoint keeps

    def __init__(self, size: int, obs_dim: int, action_dim: int, device: torch.device):
        self.size, self.obs_dim, self.action_dim = size, obs_dim, action_dim
        self.ptr, self.filled = 0, 0
        self.obs = torch.zeros((size, obs_dim), device=device)
        self.actions = torch.zeros((size, action_dim), device=device)
        self.rewards = torch.zeros(size, device=device)
        self.next_obs = torch.zeros((size, obs_dim), device=device)
        self.terminated = torch.zeros(size, device=device)

    def add(self, obs: np.ndarray, action: np.ndarray, reward: float, terminated: bool,
            next_obs: np.ndarray) -> None:
        """One transition, in one copy to the buffer's device."""
        packed = torch.as_tensor(np.concatenate([obs, action, [reward, terminated], next_obs],
                                                dtype=np.float32)).to(self.obs.device)
        o, a, r, t, n = packed.split([self.obs_dim, self.action_dim, 1, 1, self.obs_dim])
        i = self.ptr
        self.obs[i], self.actions[i], self.rewards[i], self.next_obs[i] = o, a, r[0], n
        self.terminated[i] = t[0]
        self.ptr, self.filled = (i + 1) % self.size, min(self.filled + 1, self.size)

    def sample(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """obs, actions, rewards, next_obs, 1 - terminated, drawn uniformly with replacement."""
        idx = torch.randint(self.filled, (batch_size,), device=self.obs.device)
        batch = (self.obs[idx], self.actions[idx], self.rewards[idx], self.next_obs[idx],
                 1 - self.terminated[idx])
        return tuple(t.to(device, non_blocking=True) for t in batch)


# The losses, written once for sac_update and for speedups.compiled_update's one graph.
def critic_loss(qf: TwinQ, qf_target: TwinQ, actor: Actor, alpha: torch.Tensor,
                batch: tuple[torch.Tensor, ...], noise: torch.Tensor,
                gamma: float) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Q1's plus Q2's mean squared error against the soft TD target; each loss and Q value."""
    obs, actions, rewards, next_obs, not_done = batch
    with torch.no_grad():
        next_actions, next_log_pi = actor.squash(*actor(next_obs), noise)
        min_qf_next = qf_target(next_obs, next_actions).min(0).values
        next_q_value = rewards + not_done * gamma * (min_qf_next - alpha * next_log_pi)
    qf_values = qf(obs, actions)
    qf_losses = (qf_values - next_q_value).pow(2).mean(-1)
    return qf_losses.sum(), (qf_losses, qf_values)


def actor_loss(actor: Actor, qf: TwinQ, alpha: torch.Tensor, obs: torch.Tensor,
               noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """alpha * log pi - min(Q1, Q2) at the policy's own actions, and their log pi."""
    pi, log_pi = actor.squash(*actor(obs), noise)
    return (alpha * log_pi - qf(obs, pi).min(0).values).mean(), log_pi


def alpha_loss(log_alpha: torch.Tensor, log_pi: torch.Tensor,
               target_entropy: float) -> torch.Tensor:
    """The temperature's loss: alpha rises while the policy's entropy is below the target."""
    return -(log_alpha.exp() * (log_pi.detach() + target_entropy)).mean()


def sac_update(actor: Actor, qf: TwinQ, qf_target: TwinQ, log_alpha: torch.Tensor,
               optimizers: tuple[torch.optim.Optimizer, ...], batch: tuple[torch.Tensor, ...],
               noise: torch.Tensor, gamma: float, tau: float,
               target_entropy: float) -> tuple[torch.Tensor, ...]:
    """One step of the critics, actor, temperature and target, all from the parameters before
    it (HumanoidBench's jaxrl_m). noise: (2, batch, A). Returns train.csv's logs."""
    actor_optimizer, q_optimizer, alpha_optimizer = optimizers
    alpha = log_alpha.exp().detach()
    qf_loss, (qf_losses, qf_values) = critic_loss(qf, qf_target, actor, alpha, batch, noise[0],
                                                  gamma)
    pi_loss, log_pi = actor_loss(actor, qf, alpha, batch[0], noise[1])
    temperature_loss = alpha_loss(log_alpha, log_pi, target_entropy)

    q_optimizer.zero_grad()
    qf_loss.backward()
    actor_optimizer.zero_grad()
    pi_loss.backward(inputs=list(actor.parameters()))  # not into the critics that score it
    alpha_optimizer.zero_grad()
    temperature_loss.backward()
    with torch.no_grad():  # before the critics' step
        for param, target_param in zip(qf.parameters(), qf_target.parameters(), strict=True):
            target_param.lerp_(param, tau)
    q_optimizer.step()
    actor_optimizer.step()
    alpha_optimizer.step()
    return (qf_losses.detach(), qf_values.detach(), pi_loss.detach(), alpha,
            temperature_loss.detach(), log_pi.detach())


def make_agent(args: Args, obs_dim: int, action_space: gym.spaces.Box,
               device: torch.device) -> dict:
    """The networks, log alpha and their optimizers, by checkpoint.pt's names; the weights from
    a generator of their own, so torch's (actions, batches) starts from the seed alone."""
    generator = torch.Generator().manual_seed(args.seed)
    actor = Actor(obs_dim, args.hidden_sizes, action_space, args.log_std_min, args.log_std_max,
                  generator).to(device)
    qf = TwinQ(obs_dim, action_space.shape[0], args.hidden_sizes, generator).to(device)
    log_alpha = torch.tensor(float(np.log(args.alpha_init)), device=device, requires_grad=True)
    # fused: one kernel per step; capturable: step counts on the GPU, as a CUDA graph needs.
    adam = functools.partial(torch.optim.Adam, fused=True, capturable=device.type == "cuda")
    return {"actor": actor, "qf": qf, "qf_target": copy.deepcopy(qf), "log_alpha": log_alpha,
            "actor_optimizer": adam(actor.parameters(), lr=args.policy_lr),
            "q_optimizer": adam(qf.parameters(), lr=args.q_lr),
            "alpha_optimizer": adam([log_alpha], lr=args.alpha_lr)}


def ends_without_bootstrap(terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
    """Whether the target drops the next state's value (not on a truncation)."""
    return terminated & ~truncated


def physics_blow_up(info: dict, episode_end: bool) -> bool:
    """Whether the last step blew up the physics (h1hand): that transition is not stored."""
    return episode_end and bool(info.get("final_info", {}).get("physics_unstable", [False])[0])


if __name__ == "__main__":
    args = cli.parse_args(Args, ALGORITHM, eval_actions)
    stop = run_folder.StopRequest()  # from the start: a signal during setup also ends in code 3
    run = run_folder.RunFolder(args, ALGORITHM, __file__, eval_actions(args))
    torch.set_num_threads(args.torch_threads)
    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002
    torch.manual_seed(args.seed)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")

    env = make_env(args.env_id)  # checks the id and the spaces
    cli.check_reset_noise(env, args.env_id, args.eval_reset_noise)
    action_space = env.action_space  # draws the random start actions
    action_space.seed(args.seed)
    envs = make_vector_env(args.env_id)
    obs_dim, action_dim = envs.single_observation_space.shape[0], action_space.shape[0]

    agent = make_agent(args, obs_dim, action_space, device)
    actor, qf, log_alpha = agent["actor"], agent["qf"], agent["log_alpha"]
    optimizers = (agent["actor_optimizer"], agent["q_optimizer"], agent["alpha_optimizer"])
    target_entropy = -args.target_entropy_scale * action_dim
    rb = ReplayBuffer(args.buffer_size, obs_dim, action_dim,
                      device if args.gpu_buffer else torch.device("cpu"))

    run.open(obs_dim, action_dim, device)  # locked, checked, logs and evaluation workers open
    obs, _ = envs.reset(seed=args.seed)
    global_step, updates_from = 0, args.learning_starts
    if run.resuming:  # the agent, buffer, random streams and episode under way of checkpoint.pt
        global_step, obs, updates_from = run.resume(agent, rb, action_space, envs)

    def act(obs: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return actor.squash(*actor(obs), noise)[0]

    update = functools.partial(sac_update, actor, qf, agent["qf_target"], log_alpha, optimizers,
                               gamma=args.gamma, tau=args.tau, target_entropy=target_entropy)
    if args.compile:  # the same losses, their gradients and Adam in one graph: speedups.py
        act = speedups.compile_at_start(act, (torch.zeros((1, obs_dim), device=device),
                                              torch.zeros((1, action_dim), device=device)))
        update = speedups.compiled_update(agent, (critic_loss, actor_loss, alpha_loss),
                                          args.gamma, args.tau, target_entropy,
                                          (args.batch_size, obs_dim, action_dim), device)
    if device.type == "cuda" and args.cudagraphs:  # one replay instead of ~300 kernel launches
        act, update = speedups.cuda_graph(act), speedups.cuda_graph(update, agent.values())

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
        if not physics_blow_up(info, episode_end):
            rb.add(obs[0], action[0], reward[0],
                   ends_without_bootstrap(terminated, truncated)[0], final_obs)
        obs = next_obs
        run.count_step(reward[0], episode_end)

        if global_step >= updates_from:  # --learning-starts (later after a restart)
            batch = rb.sample(args.batch_size, device)
            losses = update(batch, torch.randn((2, args.batch_size, action_dim), device=device))

        if global_step % args.log_interval == 0:
            run.log_train(global_step, losses)
        if global_step % args.eval_interval == 0:
            run.evaluate(global_step, actor, qf)  # eval_actions(args), in a worker process
        run.poll_evaluations()
        if global_step % args.print_interval == 0:
            run.print_progress(global_step)
        if args.snapshot_interval > 0 and global_step % args.snapshot_interval == 0:
            run.save_snapshot(global_step, actor, qf, log_alpha)
        if stop.requested or (args.checkpoint_interval > 0  # a stop's checkpoint ends the run
                              and global_step % args.checkpoint_interval == 0):
            run.checkpoint(global_step, agent, rb, action_space, envs, stop.requested)

    run.finish(global_step, actor, qf)
