"""Soft Actor-Critic, corrected: evaluates with the mode of the tanh-squashed Gaussian policy.

Defaults are the paper's protocol (its Tables I and II) and HumanoidBench's SAC details. The run
folder layout (config.json, eval.csv, train.csv, TensorBoard, checkpoint.pt, final_model.pt,
done.json) is described in README.md. Training is sac_standard.py's, step for step; only the
evaluation action changes: `diff` the two files to see the correction. Each evaluation round also
acts with tanh(mu) from the same start states (a paired comparison on the same actor) and logs how
far the mode is from tanh(mu): the paper's distribution shift, measured during training.
"""

import copy
import csv
import dataclasses
import difflib
import fcntl
import functools
import importlib
import json
import math
import os
import platform
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, NoReturn

import gymnasium as gym
import mujoco
import numpy as np
import torch
import torch.nn as nn
import tyro
from torch.utils.tensorboard import SummaryWriter

import humanoid_envs  # noqa: F401  (registers the h1hand-*-v0 tasks)
from eval_runner import EvalPool, Round, default_workers, eval_columns, eval_seeds, round_statistics

ALGORITHM = "corrected"
# eval.csv's shift columns: how far the mode is from tanh(mu) at the states the mode visits.
SHIFT_OF = ""


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
    eval_selectors: tuple[Literal["mode", "tanh_mu", "mean", "q_best"], ...] = ()
    """more evaluation actions, each paired (same start states) with the script's own: "mean"
    (E[tanh(u)]), "q_best" (the critic's pick of tanh(mu), mode and mean at each state), "mode",
    "tanh_mu" (see eval_runner.py); eval.csv columns <name>_*"""
    mode_solver: Literal["exact", "grid"] = "exact"
    """how to find the mode (for the evaluation actions that use it): "exact" (iterative solve)
    or "grid" (the paper's Algorithm 1)"""
    eval_workers: int | None = None
    """processes that run evaluation rounds while training goes on (default: the cores that
    training leaves free); 0 runs each round in-process, training waiting"""
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
    """checkpoint at the first episode end after every this many steps (0: off)"""
    cuda: bool = True
    """use a CUDA GPU if there is one"""
    cudagraphs: bool = True
    """on CUDA: capture the update (batch sampling included) and the actions as CUDA graphs"""
    gpu_buffer: bool = True
    """on CUDA: keep the replay buffer in GPU memory (1.2 GB per 1M observations of 308 floats);
    --no-gpu-buffer keeps it in host memory and copies each batch over"""
    torch_threads: int = 1
    """torch CPU threads (1 is fastest for batch 64 on small CPUs; see README)"""
    torch_deterministic: bool = True
    """if toggled, `torch.backends.cudnn.deterministic=True`"""
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


# Flags that may differ when resuming: they change where and how fast, not what is computed.
TRACKING_FIELDS = ("track", "wandb_project_name", "wandb_entity", "wandb_group")
RUNTIME_FIELDS = ("output_dir", "run_name", "resume", "checkpoint_interval", "print_interval",
                  "cuda", "cudagraphs", "gpu_buffer", "torch_threads", "capture_video",
                  "eval_workers", *TRACKING_FIELDS)
TRAIN_COLUMNS = ("global_step", "wall_time", "sps", "qf1_loss", "qf2_loss", "qf1_value",
                 "qf2_value", "actor_loss", "alpha", "alpha_loss", "entropy", "episodes",
                 "episode_return_mean", "episode_length_mean")
INTERRUPTED_EXIT_CODE = 3
# What final_model.pt keeps of the arguments, so that it alone rebuilds the actor (evaluate.py).
MODEL_FIELDS = ("env_id", "hidden_sizes", "log_std_min", "log_std_max")
CHECKPOINT_KEYS = ("args", "global_step", "elapsed", "progress", "actor", "qf", "qf_target",
                   "log_alpha", "q_optimizer", "actor_optimizer", "alpha_optimizer", "buffer",
                   "rng")


def eval_actions(args: Args) -> dict[str, str]:
    """Evaluation actions (eval_runner.py) by eval.csv column prefix: the mode, tanh(mu) paired,
    and the --eval-selectors."""
    return {"": "mode", "tanh_mu_": "tanh_mu", **{f"{s}_": s for s in args.eval_selectors}}


def parse_args() -> Args:
    """Parses and checks the flags; with --resume, the run's stored arguments are the defaults
    and a flag that contradicts them is an error."""
    args = tyro.cli(Args)
    if args.resume is None:
        check_args(args)
        return args
    path = Path(args.resume) / "config.json"
    config = read_run_config(Path(args.resume))
    stored = {f.name: config[f.name] for f in dataclasses.fields(Args)
              if f.name in config and f.name not in RUNTIME_FIELDS}
    for key in ("hidden_sizes", "eval_selectors"):  # JSON lists back to the flags' tuples
        stored[key] = tuple(stored.get(key, getattr(args, key)))
    # A tracked run goes on being tracked, to the same W&B run, unless told otherwise.
    tracking = {k: config[k] for k in TRACKING_FIELDS if k in config}
    wrong = [k for k, v in (stored | tracking).items() if not same_type(v, getattr(args, k))]
    if wrong:
        fail(f"{path} holds values of the wrong type for {wrong}; it was edited or damaged: "
             "restore it, or start a new run")
    resumed = tyro.cli(Args, default=dataclasses.replace(args, **stored, **tracking))
    changed = [k for k, v in stored.items() if getattr(resumed, k) != v]
    if changed:
        fail(f"--resume {args.resume}: flags {changed} contradict the run's stored arguments; "
             "drop them or start a new run")
    check_args(resumed)
    return resumed


def same_type(value: object, default: object) -> bool:
    """Whether a config.json value can stand for a flag with this default (None: any)."""
    if default is None or value is None:
        return True
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, tuple):  # hidden_sizes holds ints, eval_selectors names
        return isinstance(value, tuple) and all(type(v) is type(default[0]) if default
                                                else type(v) is str for v in value)
    return type(value) is type(default)


def check_args(args: Args) -> None:
    """Every flag's valid range, checked before anything is created or written."""
    finite = math.isfinite
    own_actions = eval_actions(dataclasses.replace(args, eval_selectors=())).values()
    rules = (
        ("seed", args.seed >= 0, "a non-negative integer"),
        ("total_timesteps", args.total_timesteps >= 1, "at least 1"),
        ("buffer_size", args.buffer_size >= 2, "at least 2 (a transition takes two slots)"),
        ("batch_size", 1 <= args.batch_size <= args.buffer_size,
         f"between 1 and --buffer-size ({args.buffer_size})"),
        ("gamma", 0 <= args.gamma <= 1, "in [0, 1]"),
        ("tau", 0 < args.tau <= 1, "in (0, 1]"),
        ("learning_starts", 0 <= args.learning_starts < args.total_timesteps,
         f"in [0, --total-timesteps ({args.total_timesteps})), or no gradient update would run"),
        ("policy_lr", finite(args.policy_lr) and args.policy_lr > 0, "a positive number"),
        ("q_lr", finite(args.q_lr) and args.q_lr > 0, "a positive number"),
        ("alpha_lr", finite(args.alpha_lr) and args.alpha_lr > 0, "a positive number"),
        ("alpha_init", finite(args.alpha_init) and args.alpha_init > 0, "a positive number"),
        ("target_entropy_scale", finite(args.target_entropy_scale), "a finite number"),
        ("hidden_sizes", len(args.hidden_sizes) > 0 and min(args.hidden_sizes) >= 1,
         "one or more positive layer widths, e.g. --hidden-sizes 256 256"),
        ("log_std_max", finite(args.log_std_max), "a finite number"),
        ("log_std_min", finite(args.log_std_min) and args.log_std_min < args.log_std_max,
         f"a finite number below --log-std-max ({args.log_std_max})"),
        ("eval_interval", args.eval_interval >= 1, "at least 1 (above --total-timesteps: no "
         "evaluation)"),
        ("eval_episodes", args.eval_episodes >= 1, "at least 1 (to skip evaluation, set "
         "--eval-interval above --total-timesteps)"),
        ("eval_selectors", len(set(eval_actions(args).values())) == len(eval_actions(args)),
         f"evaluation actions other than this script's own ({', '.join(own_actions)}), each once"),
        ("eval_workers", args.eval_workers is None or args.eval_workers >= 0,
         "0 (in-process) or more"),
        ("log_interval", args.log_interval >= 1, "at least 1"),
        ("print_interval", args.print_interval >= 1, "at least 1"),
        ("checkpoint_interval", args.checkpoint_interval >= 0, "0 (off) or more"),
        ("torch_threads", args.torch_threads >= 1, "at least 1"),
        ("run_name", args.run_name is None or (args.run_name not in ("", ".", "..")
                                               and "/" not in args.run_name),
         "a folder name without '/'"),
        ("wandb_project_name", bool(args.wandb_project_name), "a non-empty name"),
    )
    for name, ok, allowed in rules:
        if not ok:
            value = getattr(args, name)
            shown = " ".join(map(str, value)) if isinstance(value, tuple) else repr(value)
            fail(f"--{name.replace('_', '-')} {shown}: must be {allowed}")


def fail(message: str) -> NoReturn:
    """Bad input: one line naming the problem and the fix on stderr, exit code 2."""
    print(f"{Path(sys.argv[0]).name}: error: {message}", file=sys.stderr, flush=True)
    sys.exit(2)


def read_run_config(run_dir: Path) -> dict:
    """The config.json of a run folder made by this script, or a clear error."""
    path = run_dir / "config.json"
    if not path.is_file():
        fail(f"{run_dir} is not a run folder (no config.json); give --resume a folder made by "
             "sac_standard.py or sac_corrected.py")
    try:
        config = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        fail(f"{path} is not valid JSON ({error}); restore it from a copy, or start a new run")
    if not isinstance(config, dict):
        fail(f"{path} does not hold a JSON object; restore it from a copy, or start a new run")
    if config.get("algorithm") != ALGORITHM:
        fail(f"{run_dir} is a run of {config.get('script')}; resume it with that script")
    return config


def make_env(env_id: str, render: bool = False) -> gym.Env:
    """The gymnasium env, with a clear error for an id or a space that SAC cannot use. An id
    "package.module:EnvId" imports the module first, which registers the env (gymnasium's way)."""
    module, _, name = env_id.rpartition(":")
    if module:
        try:
            importlib.import_module(module)
        except ImportError as error:
            fail(f"--env-id {env_id}: cannot import {module!r} ({error}); check the module path "
                 "(run from the folder that holds it)")
    if name not in gym.registry:
        close = difflib.get_close_matches(name, list(gym.registry), n=5, cutoff=0.5)
        ours = sorted(k for k in gym.registry if k.startswith("h1hand-"))
        fail(f"unknown env id {env_id!r}; close matches: {close}; our tasks: {ours}")
    env = gym.make(env_id, **({"render_mode": "rgb_array"} if render else {}))
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        fail(f"{env_id} has a {type(space).__name__} action space; SAC needs a Box")
    if not (np.isfinite(space.low).all() and np.isfinite(space.high).all()):
        fail(f"{env_id} has unbounded actions; SAC squashes into finite bounds")
    obs_space = env.observation_space
    if not isinstance(obs_space, gym.spaces.Box) or len(obs_space.shape) != 1:
        fail(f"{env_id} observations are not a flat Box; flatten them first")
    return env


def init_glorot(module: nn.Module) -> None:
    """Glorot-uniform weights and zero biases on every layer, output heads included: HumanoidBench's
    jaxrl_m networks (flax's variance_scaling(1, "fan_avg", "uniform")), not PyTorch's default."""
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            nn.init.xavier_uniform_(layer.weight)
            nn.init.zeros_(layer.bias)


class Actor(nn.Module):
    def __init__(self, obs_dim: int, hidden: tuple[int, ...], action_space: gym.spaces.Box,
                 log_std_min: float, log_std_max: float):
        super().__init__()
        sizes = (obs_dim, *hidden)
        self.trunk = nn.Sequential(*[m for i, o in zip(sizes, sizes[1:], strict=False)
                                     for m in (nn.Linear(i, o), nn.ReLU())])
        action_dim = int(np.prod(action_space.shape))
        self.fc_mean = nn.Linear(sizes[-1], action_dim)
        self.fc_logstd = nn.Linear(sizes[-1], action_dim)
        low, high = (torch.as_tensor(b, dtype=torch.float32) for b in (action_space.low,
                                                                      action_space.high))
        self.register_buffer("action_scale", (high - low) / 2)
        self.register_buffer("action_bias", (high + low) / 2)
        self.log_std_min, self.log_std_max = log_std_min, log_std_max
        init_glorot(self)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """mu and log sigma of the Gaussian before the tanh squashing."""
        h = self.trunk(obs)
        return self.fc_mean(h), self.fc_logstd(h).clamp(self.log_std_min, self.log_std_max)

    def get_action(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised sample scale * tanh(u) + bias, u ~ N(mu, sigma^2), and its
        log-density."""
        mu, log_std = self(obs)
        noise = torch.randn_like(mu)
        u = mu + noise * log_std.exp()
        # log N(u) - log|d tanh(u)/du| - log(scale), with the stable form of log(1 - tanh(u)^2).
        log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * np.log(2 * np.pi)
                    - 2 * (np.log(2) - u - nn.functional.softplus(-2 * u))
                    - self.action_scale.log())
        return self.scale(torch.tanh(u)), log_prob.sum(1)

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        """Maps a squashed action in (-1, 1)^A to the env's bounds."""
        return y * self.action_scale + self.action_bias


class TwinQ(nn.Module):
    """The twin critics Q1 and Q2 (the target takes their minimum). Two plain MLPs: fusing them
    into batched matmuls measured no faster on CPU (bench/bench_sac.py)."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...]):
        super().__init__()
        sizes = (obs_dim + action_dim, *hidden, 1)
        self.qf1, self.qf2 = (nn.Sequential(*[m for i, o in zip(sizes, sizes[1:], strict=False)
                                              for m in (nn.Linear(i, o), nn.ReLU())][:-1])
                              for _ in range(2))
        init_glorot(self)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q1 and Q2 of each (obs, action), shape (2, batch)."""
        x = torch.cat([obs, action], 1)
        return torch.stack([self.qf1(x), self.qf2(x)]).squeeze(-1)


class ReplayBuffer:
    """Stores each observation once, in float32 tensors on `device`: slot i's next observation is
    in slot i + 1.

    An episode's last transition is followed by a slot holding only its final observation (never
    sampled), so a truncated episode keeps its true final observation for bootstrapping and no
    transition spans a reset. On a GPU the buffer lives there and a batch is drawn without a
    host synchronisation, so the whole update, sampling included, can be one CUDA graph."""

    # Slots drawn per batch row; the row takes the first that holds a transition (see sample).
    CANDIDATES = 16
    ARRAYS = ("obs", "actions", "rewards", "terminated", "valid")

    def __init__(self, size: int, obs_dim: int, action_dim: int, device: torch.device):
        self.size, self.ptr, self.filled = size, 0, 0
        self.obs = torch.zeros((size, obs_dim), device=device)
        self.actions = torch.zeros((size, action_dim), device=device)
        self.rewards = torch.zeros(size, device=device)
        self.terminated = torch.zeros(size, device=device)
        self.valid = torch.zeros(size, dtype=torch.bool, device=device)  # slot i: a transition
        self.filled_tensor = torch.zeros((), dtype=torch.int64, device=device)  # read in graphs

    def add(self, obs, action, reward, terminated, next_obs, episode_end: bool) -> None:
        i, j = self.ptr, (self.ptr + 1) % self.size
        self.obs[i], self.actions[i] = torch.as_tensor(obs), torch.as_tensor(action)
        self.rewards[i], self.terminated[i], self.valid[i] = float(reward), float(terminated), True
        self.obs[j], self.valid[j] = torch.as_tensor(next_obs), False
        self.ptr = (j + 1) % self.size if episode_end else j
        self.filled = self.size if j == 0 else max(self.filled, j + 1)
        self.filled_tensor.fill_(self.filled)

    def sample(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """Uniform over stored transitions: obs, actions, rewards, next_obs, 1 - terminated.

        Each row draws CANDIDATES slots from the torch generator of the buffer's device and keeps
        the first that holds a transition (rejection sampling with a fixed number of tries, so
        no data-dependent loop). If all of them are final-observation slots, which has
        probability (episodes / slots)^16 (below 1e-16 for episodes of 10 steps or more), the row
        takes the slot before: that episode's last transition."""
        slots = torch.randint(2**62, (self.CANDIDATES, batch_size),
                              device=self.obs.device) % self.filled_tensor
        first = self.valid[slots].byte().argmax(0)  # argmax returns the first maximum
        idx = slots.gather(0, first[None])[0]
        idx = torch.where(self.valid[idx], idx, (idx - 1) % self.size)
        batch = (self.obs[idx], self.actions[idx], self.rewards[idx],
                 self.obs[(idx + 1) % self.size], 1 - self.terminated[idx])
        return tuple(t.to(device, non_blocking=True) for t in batch)

    def state_dict(self) -> dict:
        """The filled slots as CPU tensors: a checkpoint loads on any device."""
        n = self.filled
        # On the CPU, from_numpy of the slice makes torch.save write n rows, not the storage.
        rows = (lambda t: torch.from_numpy(t[:n].numpy())) if self.obs.device.type == "cpu" \
            else (lambda t: t[:n].cpu())
        return {"ptr": self.ptr, "filled": n, **{k: rows(getattr(self, k)) for k in self.ARRAYS}}

    def load_state_dict(self, state: dict) -> None:
        self.ptr, self.filled = state["ptr"], state["filled"]
        self.filled_tensor.fill_(self.filled)
        for k in self.ARRAYS:
            getattr(self, k)[: self.filled].copy_(state[k])


def sac_update(batch: tuple[torch.Tensor, ...], actor: Actor, qf: TwinQ, qf_target: TwinQ,
               log_alpha: torch.Tensor, optimizers: tuple[torch.optim.Optimizer, ...],
               gamma: float, tau: float, target_entropy: float) -> tuple[torch.Tensor, ...]:
    """One gradient step of the twin critics, the actor and the temperature, and the critics'
    Polyak-averaged targets. Returns the tensors that train.csv logs."""
    b_obs, b_actions, b_rewards, b_next_obs, b_not_done = batch
    alpha = log_alpha.exp().detach()
    with torch.no_grad():
        next_actions, next_log_pi = actor.get_action(b_next_obs)
        min_qf_next = qf_target(b_next_obs, next_actions).min(0).values
        next_q_value = b_rewards + b_not_done * gamma * (min_qf_next - alpha * next_log_pi)
    qf_values = qf(b_obs, b_actions)
    qf_losses = (qf_values - next_q_value).pow(2).mean(1)
    pi, log_pi = actor.get_action(b_obs)
    actor_loss = (alpha * log_pi - qf(b_obs, pi).min(0).values).mean()
    alpha_loss = -(log_alpha.exp() * (log_pi.detach() + target_entropy)).mean()

    # As HumanoidBench's jaxrl_m: all three losses use the parameters from before this update
    # (the actor is scored by the pre-update critic), and the target moves towards that critic.
    for optimizer in optimizers:
        optimizer.zero_grad()
    qf_losses.sum().backward()
    # Only the actor's gradients: autograd then skips the critics' weight gradients.
    actor_loss.backward(inputs=list(actor.parameters()))
    alpha_loss.backward()
    with torch.no_grad():
        for p, p_target in zip(qf.parameters(), qf_target.parameters(), strict=True):
            p_target.lerp_(p, tau)
    for optimizer in optimizers:
        optimizer.step()
    return qf_losses, qf_values, actor_loss, alpha, alpha_loss, log_pi


def evaluation_round(args: Args, actor: Actor, qf: TwinQ, actions: dict[str, str],
                     global_step: int, wall_time: float, run_dir: Path) -> Round:
    """The evaluation round at this step, on CPU copies of the networks: training goes on while
    a worker runs it (eval_runner.py)."""
    eval_round = global_step // args.eval_interval
    videos = {"": run_dir / "videos" / f"eval_step{global_step}.mp4"} if args.capture_video \
        else {}
    if videos:
        videos[""].parent.mkdir(exist_ok=True)
    return Round(args.env_id, eval_seeds(args.seed, eval_round, args.eval_episodes), actions,
                 copy.deepcopy(actor).cpu(),
                 copy.deepcopy(qf).cpu() if "q_best" in actions.values() else None,
                 mode_solver=args.mode_solver, shift_of=SHIFT_OF, videos=videos,
                 label=f"evaluation at step {global_step}",
                 info={"global_step": global_step, "wall_time": wall_time,
                       "eval_round": eval_round})


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


def make_train_step(rb: ReplayBuffer, update: Callable, batch_size: int, device: torch.device,
                    graphs: bool, learner: tuple) -> Callable:
    """One gradient update on a fresh batch, as a function of nothing. With graphs and the buffer
    on the GPU, sampling is inside the graph; with the buffer in host memory, the batch is drawn
    there and copied into the graph's inputs."""
    if not graphs:
        return lambda: update(rb.sample(batch_size, device))
    if rb.obs.device.type == device.type:  # the buffer is on the run's GPU
        return cuda_graph(lambda: update(rb.sample(batch_size, device)), learner)
    update_graph = cuda_graph(lambda *batch: update(batch), learner)
    return lambda: update_graph(*rb.sample(batch_size, device))


def check_finite(x: np.ndarray, what: str) -> None:
    if not np.isfinite(x).all():
        raise SystemExit(f"non-finite {what} (NaN/inf): training diverged; try lower learning "
                         "rates or resume from an earlier checkpoint")


def ends_without_bootstrap(terminated: bool, truncated: bool) -> bool:
    """Whether the target of a transition drops the next state's value. HumanoidBench bootstraps
    one that is both terminated and truncated (its mask is `not terminated or truncated`)."""
    return terminated and not truncated


def train_statistics(progress: dict, losses: tuple[torch.Tensor, ...] | None) -> dict:
    """train.csv's statistics: the last update's losses (none before learning starts) and the
    training episodes that ended since the previous row (taken out of `progress`)."""
    returns, lengths = progress["episode_returns"], progress["episode_lengths"]
    row = {"episodes": len(returns),
           "episode_return_mean": np.mean(returns) if returns else None,
           "episode_length_mean": np.mean(lengths) if lengths else None}
    returns.clear()
    lengths.clear()
    if losses is not None:
        qf_losses, qf_values, actor_loss, alpha, alpha_loss, log_pi = losses
        check_finite(qf_losses.detach().cpu().numpy(), "critic loss")
        row |= {"qf1_loss": qf_losses[0].item(), "qf2_loss": qf_losses[1].item(),
                "qf1_value": qf_values[0].mean().item(), "qf2_value": qf_values[1].mean().item(),
                "actor_loss": actor_loss.item(), "alpha": alpha.item(),
                "alpha_loss": alpha_loss.item(), "entropy": -log_pi.mean().item()}
    return row


def open_csv(path: Path, columns: list[str], keep_until_step: int | None):
    """An append-mode CSV writer. Resuming keeps the whole rows up to the checkpoint's step, so
    the file ends up with no duplicate or missing rows."""
    kept = []
    if keep_until_step is not None and path.exists():
        lines = path.read_text().splitlines(keepends=True)[1:]
        kept = [r for r in lines if r.endswith("\n") and int(r.split(",")[0]) <= keep_until_step]
    atomic_write(path, lambda tmp: tmp.write_text(",".join(columns) + "\n" + "".join(kept)))
    f = open(path, "a", newline="")  # noqa: SIM115  (kept open for the whole run)
    return f, csv.DictWriter(f, columns)


def check_csv(path: Path, columns: list[str]) -> None:
    """Before a resume writes anything: the CSV must be this run's (its header, whole steps)."""
    if not path.exists():
        return
    lines = path.read_text(errors="replace").splitlines(keepends=True)
    if not lines or lines[0].rstrip("\r\n").split(",") != columns:
        fail(f"{path} does not have the header this run writes ({len(columns)} columns: "
             f"{', '.join(columns[:3])}, ...); it was edited or belongs to another run: restore "
             "it, or move it away to drop its rows")
    for number, line in enumerate(lines[1:], start=2):
        if line.endswith("\n") and not line.split(",")[0].isdigit():
            fail(f"{path}, line {number}: global_step {line.split(',')[0]!r} is not a step "
                 "number; restore the file, or delete that line")


def read_checkpoint(path: Path) -> dict:
    """checkpoint.pt on the CPU (RNG states must stay there; load_state_dict moves the rest to
    the run's device), or one line saying it is damaged."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False, mmap=True)
        missing = [k for k in CHECKPOINT_KEYS if k not in ckpt]
    except Exception as error:  # a truncated or foreign file fails in pickle, zip or torch
        fail(f"{path} cannot be read ({type(error).__name__}: {str(error).splitlines()[0]}); "
             "it is damaged: restore a copy, or delete it to restart the run from step 0")
    if missing:
        fail(f"{path} lacks {missing}: not a checkpoint of this script; restore a copy, or "
             "delete it to restart the run from step 0")
    return ckpt


def write_row(f, writer: csv.DictWriter, tb: SummaryWriter, tracker, group: str, row: dict,
              video: Path | None = None) -> None:
    """One row to its CSV (flushed), to TensorBoard and, with --track, to W&B."""
    writer.writerow(row)
    f.flush()
    scalars = {f"{group}/{k}": v for k, v in row.items()
               if v is not None and k not in ("global_step", "wall_time")}
    for k, v in scalars.items():
        tb.add_scalar(k, v, row["global_step"])
    if tracker is not None:
        import wandb  # only with --track

        media = {f"{group}/video": wandb.Video(str(video), format="mp4")} if video else {}
        tracker.log({"global_step": row["global_step"], **scalars, **media})


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Writes via a temporary file and os.replace: a kill leaves the old file or the new one."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def start_tracking(args: Args, run_dir: Path):
    """With --track, the W&B run, as CleanRL logs it: the config, every scalar that goes to
    TensorBoard (against global_step) and the evaluation videos. wandb is imported only here.
    Its id is kept in the run folder, so a resumed run continues the same W&B run; with
    WANDB_MODE=offline it writes to run_dir/wandb, for `wandb sync` later."""
    if not args.track:
        return None
    import wandb
    from wandb.sdk.lib.runid import generate_id

    id_file = run_dir / "wandb_run_id.txt"
    if not id_file.exists():
        atomic_write(id_file, lambda tmp: tmp.write_text(generate_id() + "\n"))
    tracker = wandb.init(project=args.wandb_project_name, entity=args.wandb_entity,
                         group=args.wandb_group, name=run_dir.name, dir=run_dir,
                         id=id_file.read_text().strip(), resume="allow",
                         config=dataclasses.asdict(args) | {"algorithm": ALGORITHM})
    tracker.define_metric("*", step_metric="global_step")
    return tracker


def run_metadata(args: Args, obs_dim: int, action_dim: int) -> dict:
    """config.json: every argument, the algorithm, the library versions and the git commit."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                                capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    return {**dataclasses.asdict(args), "algorithm": ALGORITHM, "script": Path(__file__).name,
            "obs_dim": obs_dim, "action_dim": action_dim, "git_commit": commit,
            "versions": {"python": platform.python_version(), "torch": torch.__version__,
                         "numpy": np.__version__, "gymnasium": gym.__version__,
                         "mujoco": mujoco.__version__},
            "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}


def lock_run_folder(run_dir: Path) -> int:
    """An exclusive OS lock on run_dir/lock, held while this process lives: one writer per run
    folder (a Slurm requeue racing a job that has not died yet, a sweep started twice). The kernel
    drops it when the process dies, SIGKILL included, so it is never stale. Returns its fd, for
    record_holder once the folder has been checked (a refused start changes nothing)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(run_dir / "lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        fail(f"{run_dir} is in use by process {holder} (it holds {run_dir / 'lock'}); let it "
             "finish or stop it, then --resume")
    return fd


def record_holder(lock_fd: int) -> None:
    """Writes this process's pid into the lock file it holds, for a refused second process."""
    os.ftruncate(lock_fd, 0)
    os.pwrite(lock_fd, f"{os.getpid()}\n".encode(), 0)


class StopRequest:
    """SIGTERM/SIGUSR1/SIGUSR2 ask for a graceful stop at the next episode end; a second signal
    exits at once (the last checkpoint stays valid)."""

    def __init__(self):
        self.requested = False
        for s in (signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
            signal.signal(s, self.handle)

    def handle(self, signum, frame) -> None:
        if self.requested:
            print("second signal: exiting now; resume with --resume from the last checkpoint",
                  flush=True)
            os._exit(INTERRUPTED_EXIT_CODE)
        self.requested = True
        print(f"{signal.Signals(signum).name}: checkpointing at the end of this episode, then "
              "exiting", flush=True)


def rng_states(env: gym.Env) -> dict:
    """Every random stream training draws from. Nothing of ours uses the global numpy and python
    generators; libraries might."""
    name, keys, pos, has_gauss, gauss = np.random.get_state()  # noqa: NPY002
    # Plain lists, not arrays: a checkpoint then loads with torch.load(weights_only=True).
    return {"python": random.getstate(), "numpy": (name, keys.tolist(), pos, has_gauss, gauss),
            "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
            "env": env.unwrapped.np_random.bit_generator.state,
            "action_space": env.action_space.np_random.bit_generator.state}


def set_rng_states(states: dict, env: gym.Env) -> None:
    random.setstate(states["python"])
    name, keys, pos, has_gauss, gauss = states["numpy"]
    np.random.set_state((name, np.array(keys, np.uint32), pos, has_gauss, gauss))  # noqa: NPY002
    torch.set_rng_state(states["torch"])
    if states["cuda"] is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])
    env.unwrapped.np_random.bit_generator.state = states["env"]
    env.action_space.np_random.bit_generator.state = states["action_space"]


if __name__ == "__main__":
    args = parse_args()
    stop = StopRequest()  # from the start, so a signal during setup also ends in exit code 3
    torch.set_num_threads(args.torch_threads)
    if args.resume is not None:
        run_dir = Path(args.resume)
    else:
        run_name = args.run_name or (f"{args.env_id}__{ALGORITHM}__seed{args.seed}__"
                                     f"{time.strftime('%Y%m%d-%H%M%S')}")
        run_dir = Path(args.output_dir) / run_name
        if (run_dir / "config.json").exists():
            fail(f"{run_dir} already holds a run; continue it with --resume {run_dir} or choose "
                 "another --run-name")
    if (run_dir / "done.json").exists():
        print(f"{run_dir} has already finished (done.json); nothing to do")
        sys.exit(0)

    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    print(f"device: {device}" + (" (no CUDA GPU found)" if args.cuda and device.type == "cpu"
                                 else ""), flush=True)

    env = make_env(args.env_id)
    env.action_space.seed(args.seed)
    obs_dim, action_dim = env.observation_space.shape[0], int(np.prod(env.action_space.shape))

    actor = Actor(obs_dim, args.hidden_sizes, env.action_space, args.log_std_min,
                  args.log_std_max).to(device)
    qf = TwinQ(obs_dim, action_dim, args.hidden_sizes).to(device)
    qf_target = TwinQ(obs_dim, action_dim, args.hidden_sizes).to(device)
    qf_target.load_state_dict(qf.state_dict())
    # capturable: Adam's step counts stay on the GPU, as a CUDA graph needs (eager runs too, so
    # that a graph run and an eager run compute the same update).
    adam = functools.partial(torch.optim.Adam, fused=True, capturable=device.type == "cuda")
    q_optimizer = adam(qf.parameters(), lr=args.q_lr)
    actor_optimizer = adam(actor.parameters(), lr=args.policy_lr)
    target_entropy = -args.target_entropy_scale * action_dim
    log_alpha = torch.tensor(float(np.log(args.alpha_init)), device=device, requires_grad=True)
    alpha_optimizer = adam([log_alpha], lr=args.alpha_lr)
    optimizers = (q_optimizer, actor_optimizer, alpha_optimizer)
    rb = ReplayBuffer(args.buffer_size, obs_dim, action_dim,
                      device if args.gpu_buffer else torch.device("cpu"))

    actions = eval_actions(args)
    eval_header = ["global_step", "wall_time", "eval_round",
                   *eval_columns(actions, shift=SHIFT_OF is not None)]

    lock = lock_run_folder(run_dir)  # before anything in it is read or written
    # A run folder: fresh, or resumed from its checkpoint, or restarted if it has none yet.
    checkpoint_path = run_dir / "checkpoint.pt"
    ckpt = read_checkpoint(checkpoint_path) \
        if args.resume is not None and checkpoint_path.exists() else None
    if ckpt is not None:
        config_args = {k: v for k, v in ckpt["args"].items() if k not in RUNTIME_FIELDS}
        wanted = {k: v for k, v in dataclasses.asdict(args).items() if k not in RUNTIME_FIELDS}
        if config_args != wanted:
            fail(f"{checkpoint_path} was made with other arguments than "
                 f"{run_dir / 'config.json'}; the run folder is inconsistent")
        check_csv(run_dir / "eval.csv", eval_header)  # before anything is written
        check_csv(run_dir / "train.csv", list(TRAIN_COLUMNS))
        for module, key in ((actor, "actor"), (qf, "qf"), (qf_target, "qf_target"),
                            (q_optimizer, "q_optimizer"), (actor_optimizer, "actor_optimizer"),
                            (alpha_optimizer, "alpha_optimizer"), (rb, "buffer")):
            module.load_state_dict(ckpt[key])
        for group in (g for optimizer in optimizers for g in optimizer.param_groups):
            group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
        with torch.no_grad():
            log_alpha.copy_(ckpt["log_alpha"])
        set_rng_states(ckpt["rng"], env)
        global_step, elapsed, progress = ckpt["global_step"], ckpt["elapsed"], ckpt["progress"]
        obs, _ = env.reset()  # the checkpoint was taken at an episode end, before this reset
        print(f"resuming {run_dir} at step {global_step}", flush=True)
    else:
        run_dir.mkdir(parents=True, exist_ok=True)
        for old in run_dir.glob("events.out.tfevents.*"):  # a restart from step 0
            old.unlink()
        global_step, elapsed = 0, 0.0
        progress = {"episode_returns": [], "episode_lengths": [], "last_eval": None}
        atomic_write(run_dir / "config.json", lambda tmp: tmp.write_text(json.dumps(
            run_metadata(args, obs_dim, action_dim), indent=2)))
        obs, _ = env.reset(seed=args.seed)
    record_holder(lock)
    keep = global_step if args.resume is not None else None
    graphs = device.type == "cuda" and args.cudagraphs
    graphed = cuda_graph if graphs else (lambda fn, restore=(): fn)
    train_action = graphed(torch.no_grad()(lambda obs: actor.get_action(obs)[0]))
    train_step = make_train_step(
        rb, lambda batch: sac_update(batch, actor, qf, qf_target, log_alpha, optimizers,
                                     args.gamma, args.tau, target_entropy),
        args.batch_size, device, graphs, (actor, qf, qf_target, log_alpha, *optimizers))
    eval_file, eval_csv = open_csv(run_dir / "eval.csv", eval_header, keep)
    train_file, train_csv = open_csv(run_dir / "train.csv", list(TRAIN_COLUMNS), keep)
    tb = SummaryWriter(run_dir, purge_step=global_step + 1 if ckpt is not None else None)
    if ckpt is None:
        tb.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(
            f"|{k}|{v}|" for k, v in dataclasses.asdict(args).items()))
    del ckpt
    tracker = start_tracking(args, run_dir)

    def log_evaluation(round_: Round, result: dict) -> None:
        """An evaluation round's eval.csv row; EvalPool calls this in step order."""
        row = dict(round_.info)
        for prefix in actions:
            row |= round_statistics(result, prefix)
        write_row(eval_file, eval_csv, tb, tracker, "eval", row | result.get("shift", {}),
                  round_.videos.get(""))
        progress["last_eval"] = (row["global_step"], row["return_mean"])

    eval_pool = EvalPool(default_workers() if args.eval_workers is None else args.eval_workers,
                         log_evaluation)

    session_start, row_start, row_step = time.time(), time.time(), global_step
    episode_return, episode_length, losses = 0.0, 0, None
    next_checkpoint = (global_step // args.checkpoint_interval + 1) * args.checkpoint_interval \
        if args.checkpoint_interval > 0 else None
    while global_step < args.total_timesteps:
        if global_step < args.learning_starts:
            action = env.action_space.sample()
        else:
            obs_tensor = torch.as_tensor(obs, dtype=torch.float32, device=device)[None]
            action = train_action(obs_tensor)[0].cpu().numpy()
            check_finite(action, "action")
        next_obs, reward, terminated, truncated, info = env.step(action)
        global_step += 1
        episode_return, episode_length = episode_return + float(reward), episode_length + 1
        episode_end = terminated or truncated
        rb.add(obs, action, reward, ends_without_bootstrap(terminated, truncated), next_obs,
               episode_end)
        obs = next_obs

        if global_step >= args.learning_starts:
            losses = train_step()

        if global_step % args.log_interval == 0:
            now = time.time()
            row = {"global_step": global_step, "wall_time": elapsed + now - session_start,
                   "sps": (global_step - row_step) / (now - row_start),
                   **train_statistics(progress, losses)}
            write_row(train_file, train_csv, tb, tracker, "train", row)
            row_start, row_step = now, global_step

        if global_step % args.eval_interval == 0:
            eval_pool.submit(evaluation_round(args, actor, qf, actions, global_step,
                                              elapsed + time.time() - session_start, run_dir))
        eval_pool.poll()

        if global_step % args.print_interval == 0:
            last = progress["last_eval"]
            print(f"step {global_step:,}/{args.total_timesteps:,} | "
                  f"{global_step / (elapsed + time.time() - session_start):.0f} SPS overall | "
                  + (f"last eval {last[1]:.1f} at step {last[0]:,}" if last else "no eval yet"),
                  flush=True)

        if episode_end:
            progress["episode_returns"].append(episode_return)
            progress["episode_lengths"].append(episode_length)
            episode_return, episode_length = 0.0, 0
            if stop.requested or (next_checkpoint is not None and global_step >= next_checkpoint):
                eval_pool.drain()  # a checkpoint follows every round before it into eval.csv
                state = {"args": dataclasses.asdict(args), "global_step": global_step,
                         "elapsed": elapsed + time.time() - session_start, "progress": progress,
                         "actor": actor.state_dict(), "qf": qf.state_dict(),
                         "qf_target": qf_target.state_dict(), "log_alpha": log_alpha.detach(),
                         "q_optimizer": q_optimizer.state_dict(),
                         "actor_optimizer": actor_optimizer.state_dict(),
                         "alpha_optimizer": alpha_optimizer.state_dict(),
                         "buffer": rb.state_dict(), "rng": rng_states(env)}
                atomic_write(checkpoint_path, lambda tmp, state=state: torch.save(state, tmp))
                del state
                if next_checkpoint is not None:
                    next_checkpoint = (global_step // args.checkpoint_interval + 1) \
                        * args.checkpoint_interval
                if stop.requested:
                    tb.close()
                    if tracker is not None:
                        tracker.finish()
                    print(f"interrupted at step {global_step}; resume with --resume {run_dir}",
                          flush=True)
                    sys.exit(INTERRUPTED_EXIT_CODE)
            obs, _ = env.reset()

    eval_pool.drain()
    eval_pool.close()
    atomic_write(run_dir / "final_model.pt", lambda tmp: torch.save(
        {"actor": actor.state_dict(), "qf": qf.state_dict(),
         "config": {k: getattr(args, k) for k in MODEL_FIELDS}}, tmp))
    tb.close()
    if tracker is not None:
        tracker.finish()
    eval_file.close()
    train_file.close()
    wall_time = elapsed + time.time() - session_start
    atomic_write(run_dir / "done.json", lambda tmp: tmp.write_text(json.dumps(
        {"global_step": global_step, "wall_time": wall_time})))
    print(f"finished {global_step} steps in {wall_time:.0f} s: {run_dir}", flush=True)
