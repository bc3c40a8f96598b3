"""Soft Actor-Critic, corrected: evaluates with the mode of the tanh-squashed Gaussian policy.

Defaults are the paper's protocol (its Tables I and II) and HumanoidBench's SAC details. The run
folder layout (config.json, eval.csv, train.csv, TensorBoard, checkpoint.pt, final_model.pt,
done.json) is described in docs/scripts.md. Training is sac_standard.py's, step for step; only the
evaluation action changes: `diff` the two files to see the correction. Each evaluation round also
acts with tanh(mu) from the same start states (a paired comparison on the same actor) and logs how
far the mode is from tanh(mu): the paper's distribution shift, measured during training.
"""

import atexit
import copy
import dataclasses
import difflib
import functools
import importlib
import json
import math
import multiprocessing
import random
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import tyro
from torch.func import functional_call
from torch.utils.tensorboard import SummaryWriter

import humanoid_envs  # noqa: F401  (registers the h1hand-*-v0 tasks)
from compiled import compile_at_start, cuda_graph, training_state  # noqa: F401
from eval_runner import EvalPool, Round, default_workers, eval_columns, eval_seeds, round_row
from run_folder import (
    INTERRUPTED_EXIT_CODE,
    EpisodeRecord,
    StopRequest,
    atomic_write,
    check_csv,
    episode_state,
    fail,
    load_optimizer_seed_states,
    load_seed_states,
    lock_run_folders,
    on_cpu,
    open_csv,
    optimizer_seed_state,
    pending_round_state,
    read_batch_checkpoints,
    read_run_config,
    record_holder,
    resume_batch_dirs,
    rng_states,
    run_metadata,
    save_batch_checkpoint,
    seed_slice,
    set_rng_states,
    start_tracking,
    write_row,
)

ALGORITHM = "corrected"
# eval.csv's shift columns: how far the mode is from tanh(mu) at the states the mode visits.
SHIFT_OF = ""


@dataclass
class Args:
    env_id: str = "h1hand-stand-v0"
    """the environment id of the task (any gymnasium env with a Box action space)"""
    seed: int = 0
    """seed of the experiment (the paper uses seeds 0-4); with --num-seeds, the first"""
    num_seeds: int = 1
    """train seeds --seed .. --seed + num_seeds - 1 side by side in this process: batched
    networks, one replay buffer and env (in a worker process) per seed, each seed in its own run
    folder; a seed's run depends on the batch it was trained in (recorded in config.json)"""
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
    """the run folder's name, {seed} in it replaced by the seed (default:
    {env_id}__{algorithm}__seed{seed}__{date-time}); with --num-seeds above 1 it needs {seed}"""
    resume: str | None = None
    """continue the batch of runs this run folder belongs to from its checkpoints, with its
    stored arguments"""
    checkpoint_interval: int = 100_000
    """checkpoint every this many steps (0: off)"""
    cuda: bool = True
    """use a CUDA GPU if there is one"""
    compile: bool = True
    """compile the gradient update (one function: sac_update) with torch.compile at start-up; on
    a CPU core it runs ~1.6x faster (docs/speed.md); needs a C++ compiler (g++)"""
    cudagraphs: bool = True
    """on CUDA: capture the update (batch sampling included) and the actions as CUDA graphs"""
    gpu_buffer: bool = True
    """on CUDA: keep the replay buffer in GPU memory (1.2 GB per 1M observations of 308 floats);
    --no-gpu-buffer keeps it in host memory and copies each batch over"""
    torch_threads: int = 1
    """torch CPU threads (1 is fastest for batch 64 on small CPUs; see docs/speed.md)"""
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
                  "cuda", "compile", "cudagraphs", "gpu_buffer", "torch_threads", "capture_video",
                  "eval_workers", *TRACKING_FIELDS)
# Of those, what a resume keeps unless told otherwise: a tracked run goes on being tracked, to
# the same W&B run; a compiled run stays compiled and an eager one eager (they round apart).
KEPT_FIELDS = (*TRACKING_FIELDS, "compile")
TRAIN_COLUMNS = ("global_step", "wall_time", "sps", "qf1_loss", "qf2_loss", "qf1_value",
                 "qf2_value", "actor_loss", "alpha", "alpha_loss", "entropy", "episodes",
                 "episode_return_mean", "episode_length_mean")
# What final_model.pt keeps of the arguments, so that it alone rebuilds the actor (evaluate.py).
MODEL_FIELDS = ("env_id", "hidden_sizes", "log_std_min", "log_std_max")


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
    config = read_run_config(Path(args.resume), ALGORITHM)
    stored = {f.name: config[f.name] for f in dataclasses.fields(Args)
              if f.name in config and f.name not in RUNTIME_FIELDS}
    for key in ("hidden_sizes", "eval_selectors"):  # JSON lists back to the flags' tuples
        stored[key] = tuple(stored.get(key, getattr(args, key)))
    # A folder's config.json holds its own seed; the batch's arguments start at its first.
    stored["seed"] = config.get("batch", {}).get("first_seed", stored.get("seed", args.seed))
    kept = {k: config[k] for k in KEPT_FIELDS if k in config}
    wrong = [k for k, v in (stored | kept).items() if not same_type(v, getattr(args, k))]
    if wrong:
        fail(f"{path} holds values of the wrong type for {wrong}; it was edited or damaged: "
             "restore it, or start a new run")
    resumed = tyro.cli(Args, default=dataclasses.replace(args, **stored, **kept))
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
        ("num_seeds", args.num_seeds >= 1, "at least 1"),
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
                                               and "/" not in args.run_name
                                               and (args.num_seeds == 1
                                                    or "{seed}" in args.run_name)),
         "a folder name without '/' (with --num-seeds above 1, containing {seed})"),
        ("wandb_project_name", bool(args.wandb_project_name), "a non-empty name"),
    )
    for name, ok, allowed in rules:
        if not ok:
            value = getattr(args, name)
            shown = " ".join(map(str, value)) if isinstance(value, tuple) else repr(value)
            fail(f"--{name.replace('_', '-')} {shown}: must be {allowed}")


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


def make_vector_env(env_id: str, num_envs: int) -> gym.vector.VectorEnv:
    """One env per seed, each in its own worker process when there are several (a single one
    steps in-process: no pipe to cross). An episode's end resets that env in the same step, its
    final observation in info["final_obs"] (gymnasium's SAME_STEP autoreset)."""
    def make() -> gym.Env:
        if multiprocessing.parent_process() is not None:  # in a worker: the trainer stops it
            for s in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
                signal.signal(s, signal.SIG_IGN)
        return EpisodeRecord(gym.make(env_id))

    vector = gym.vector.AsyncVectorEnv if num_envs > 1 else gym.vector.SyncVectorEnv
    return vector([make] * num_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)


class SeedLinear(nn.Module):
    """One linear layer per seed, K in all: weight (K, in, out), bias (K, 1, out). A batched
    matmul runs the K layers as one; each seed's gradients stay its own. A (batch, in) input is
    one seed's batch through a K = 1 layer (the evaluation's copies, see seed_slice)."""

    def __init__(self, seeds: int, in_features: int, out_features: int):
        super().__init__()
        # (in, out), not nn.Linear's (out, in): no transpose in the matmul, whose forward and
        # backward are then ~20% cheaper on a CPU (bench/bench_sac.py).
        self.weight = nn.Parameter(torch.empty(seeds, in_features, out_features))
        self.bias = nn.Parameter(torch.zeros(seeds, 1, out_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() == 2:
            return self(x[None])[0]
        return torch.baddbmm(self.bias, x, self.weight)


class ReLUFromOutput(torch.autograd.Function):
    """ReLU whose backward multiplies by sign(output), 1 where it passed and 0 where it clipped:
    torch.relu's gradient, from a float tensor instead of a boolean mask of the input, which
    inductor's CPU code stores ~10x slower (bench/bench_compile.py; the update has ten ReLUs)."""

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
    """torch.relu, as ReLUFromOutput when compiled (the same gradient; eager, under torch.func
    the custom backward costs more than it saves)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return ReLUFromOutput.apply(x) if torch.compiler.is_compiling() else torch.relu(x)


def seed_mlp(seeds: int, sizes: tuple[int, ...]) -> nn.Sequential:
    """K MLPs with ReLU between the layers, none after the last."""
    layers = [m for i, o in zip(sizes, sizes[1:], strict=False)
              for m in (SeedLinear(seeds, i, o), ReLU())]
    return nn.Sequential(*layers[:-1])


def init_glorot(module: nn.Module, generators: list[torch.Generator] | None) -> None:
    """Glorot-uniform weights and zero biases on every layer, output heads included: HumanoidBench's
    jaxrl_m networks (flax's variance_scaling(1, "fan_avg", "uniform")), not PyTorch's default.
    Seed k's layers draw from generators[k] only: a seed's networks are its own."""
    for layer in module.modules():
        if isinstance(layer, SeedLinear):
            with torch.no_grad():
                for k, weight in enumerate(layer.weight):
                    nn.init.xavier_uniform_(weight, generator=generators[k] if generators else None)


class Actor(nn.Module):
    def __init__(self, obs_dim: int, hidden: tuple[int, ...], action_space: gym.spaces.Box,
                 log_std_min: float, log_std_max: float, seeds: int = 1,
                 generators: list[torch.Generator] | None = None):
        super().__init__()
        sizes, action_dim = (obs_dim, *hidden), int(np.prod(action_space.shape))
        self.trunk = nn.Sequential(*[m for i, o in zip(sizes, sizes[1:], strict=False)
                                     for m in (SeedLinear(seeds, i, o), ReLU())])
        self.fc_mean = SeedLinear(seeds, sizes[-1], action_dim)
        self.fc_logstd = SeedLinear(seeds, sizes[-1], action_dim)
        low, high = (torch.as_tensor(b, dtype=torch.float32) for b in (action_space.low,
                                                                      action_space.high))
        self.register_buffer("action_scale", (high - low) / 2)
        self.register_buffer("action_bias", (high + low) / 2)
        self.log_std_min, self.log_std_max = log_std_min, log_std_max
        init_glorot(self, generators)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """mu and log sigma of the Gaussian before the tanh squashing, (K, batch, A)."""
        h = self.trunk(obs)
        return self.fc_mean(h), self.fc_logstd(h).clamp(self.log_std_min, self.log_std_max)

    def get_action(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A sampled action and its log-density (see squash)."""
        mu, log_std = self(obs)
        return self.squash(mu, log_std, torch.randn_like(mu))

    def squash(self, mu: torch.Tensor, log_std: torch.Tensor,
               noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The reparameterised sample scale * tanh(u) + bias, u = mu + sigma * noise, and its
        log-density."""
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
    """The twin critics Q1 and Q2 (the target takes their minimum), K of each. Two plain MLPs:
    fusing them into one batched matmul measured no faster on CPU (bench/bench_sac.py)."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: tuple[int, ...], seeds: int = 1,
                 generators: list[torch.Generator] | None = None):
        super().__init__()
        self.qf1, self.qf2 = (seed_mlp(seeds, (obs_dim + action_dim, *hidden, 1))
                              for _ in range(2))
        init_glorot(self, generators)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Q1 and Q2 of each (obs, action), shape (2, K, batch)."""
        x = torch.cat([obs, action], -1)
        return torch.stack([self.qf1(x), self.qf2(x)]).squeeze(-1)


class ReplayBuffer:
    """K replay buffers, one per seed, as (K, size, ...) float32 tensors on `device`. Each stores
    every observation once: slot i's next observation is in slot i + 1.

    An episode's last transition is followed by a slot holding only its final observation (never
    sampled), so a truncated episode keeps its true final observation for bootstrapping and no
    transition spans a reset. On a GPU the buffer lives there and a batch is drawn without a
    host synchronisation, so the whole update, sampling included, can be one CUDA graph."""

    # Slots drawn per batch row; the row takes the first that holds a transition (see sample).
    CANDIDATES = 16
    ARRAYS = ("obs", "actions", "rewards", "terminated", "valid")

    def __init__(self, seeds: int, size: int, obs_dim: int, action_dim: int,
                 device: torch.device):
        self.size, self.obs_dim, self.action_dim = size, obs_dim, action_dim
        self.ptr, self.filled = np.zeros(seeds, np.int64), np.zeros(seeds, np.int64)
        self.obs = torch.zeros((seeds, size, obs_dim), device=device)
        self.actions = torch.zeros((seeds, size, action_dim), device=device)
        self.rewards = torch.zeros((seeds, size), device=device)
        self.terminated = torch.zeros((seeds, size), device=device)
        self.valid = torch.zeros((seeds, size), dtype=torch.bool, device=device)  # a transition
        self.filled_tensor = torch.zeros(seeds, dtype=torch.int64, device=device)  # for graphs
        self.seed_index = torch.arange(seeds, device=device)[:, None]

    def add(self, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray,
            terminated: np.ndarray, next_obs: np.ndarray, episode_end: np.ndarray,
            invented: np.ndarray | None = None) -> None:
        """One transition per seed (rows); one copy to the buffer's device for all of them.

        An `invented` one (a physics blow-up: the env could not step, and reports its previous
        observation) is not stored: its episode ends at the slot holding that observation, the
        last it reached soundly, which the transition before it keeps as its next observation
        (an episode blowing up at its first step leaves nothing)."""
        invented = np.zeros(len(self.ptr), bool) if invented is None else invented
        i, j = self.ptr, (self.ptr + 1) % self.size
        packed = torch.as_tensor(np.concatenate(
            [obs, actions, rewards[:, None], terminated[:, None], next_obs], 1, dtype=np.float32))
        slots = torch.as_tensor(np.stack([i, j]))
        packed, slots = packed.to(self.obs.device), slots.to(self.obs.device)
        o, a, r, t, n = packed.split([self.obs_dim, self.action_dim, 1, 1, self.obs_dim], 1)
        k = self.seed_index[:, 0]
        ends_at = np.where(episode_end, (j + 1) % self.size, j)
        if invented.any():  # rare: write the real transitions only
            stepped = self.valid[k, (slots[0] - 1) % self.size].cpu().numpy()
            ends_at = np.where(invented, np.where(stepped, j, i), ends_at)
            k = torch.as_tensor(np.flatnonzero(~invented), device=self.obs.device)
            slots, o, a, r, t, n = slots[:, k], o[k], a[k], r[k], t[k], n[k]
        self.obs[k, slots[0]], self.actions[k, slots[0]] = o, a
        self.rewards[k, slots[0]], self.terminated[k, slots[0]] = r[:, 0], t[:, 0]
        self.valid[k, slots[0]] = True
        self.obs[k, slots[1]], self.valid[k, slots[1]] = n, False
        self.ptr = ends_at
        self.filled = np.where(invented, self.filled,
                               np.where(j == 0, self.size, np.maximum(self.filled, j + 1)))
        self.filled_tensor.copy_(torch.as_tensor(self.filled))

    def sample(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """Uniform over each seed's stored transitions: obs, actions, rewards, next_obs,
        1 - terminated, each (K, batch, ...).

        Each row draws CANDIDATES slots from the torch generator of the buffer's device and keeps
        the first that holds a transition (rejection sampling with a fixed number of tries, so
        no data-dependent loop). If all of them are final-observation slots, which has
        probability (episodes / slots)^16 (below 1e-16 for episodes of 10 steps or more), the row
        takes the slot before: that episode's last transition."""
        k = self.seed_index
        slots = torch.randint(2**62, (self.CANDIDATES, *self.filled_tensor.shape, batch_size),
                              device=self.obs.device) % self.filled_tensor[:, None]
        first = self.valid[k, slots].byte().argmax(0)  # argmax returns the first maximum
        idx = slots.gather(0, first[None])[0]
        idx = torch.where(self.valid[k, idx], idx, (idx - 1) % self.size)
        batch = (self.obs[k, idx], self.actions[k, idx], self.rewards[k, idx],
                 self.obs[k, (idx + 1) % self.size], 1 - self.terminated[k, idx])
        return tuple(t.to(device, non_blocking=True) for t in batch)

    def zero_batch(self, batch_size: int, device: torch.device) -> tuple[torch.Tensor, ...]:
        """A batch shaped as sample()'s, all zeros (for a first call that must not learn)."""
        rows = (len(self.ptr), batch_size)
        return tuple(torch.zeros((*rows, *shape), device=device) for shape in (
            (self.obs_dim,), (self.action_dim,), (), (self.obs_dim,), ()))

    def seed_state_dict(self, k: int) -> dict:
        """Seed k's filled slots as CPU tensors: a checkpoint loads on any device."""
        n = int(self.filled[k])
        # On the CPU, from_numpy of the slice makes torch.save write n rows, not the storage.
        rows = (lambda t: torch.from_numpy(t[k, :n].numpy().copy())) \
            if self.obs.device.type == "cpu" else (lambda t: t[k, :n].cpu())
        return {"ptr": int(self.ptr[k]), "filled": n, **{a: rows(getattr(self, a))
                                                          for a in self.ARRAYS}}

    def load_seed_state_dict(self, k: int, state: dict) -> None:
        self.ptr[k], self.filled[k] = state["ptr"], state["filled"]
        self.filled_tensor[k] = state["filled"]
        for a in self.ARRAYS:
            getattr(self, a)[k, : state["filled"]].copy_(state[a])


def sac_losses(params: tuple[dict, dict, torch.Tensor], qf_target_params: dict,
               batch: tuple[torch.Tensor, ...], noise: torch.Tensor, actor: Actor, qf: TwinQ,
               gamma: float, target_entropy: float) -> tuple[torch.Tensor, tuple]:
    """The critic, actor and temperature losses of every seed, summed into one number whose
    gradient holds each one's: the critics' parameters get the critic loss's (the actor loss sees
    them detached), the actor's the actor loss's, log alpha (K,) the temperature loss's. Seeds are
    summed too: each seed's gradients are its own. noise: (2, K, batch, A), the next action's and
    the action's. Also returns what train.csv logs, per seed."""
    # The networks stay nn.Modules, defined as usual; functional_call runs one on the parameters
    # given here, which is what torch.func.grad differentiates.
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
        next_q_value = b_rewards + b_not_done * gamma * (min_qf_next
                                                         - alpha[:, None] * next_log_pi)
    qf_values = q(qf_params, b_obs, b_actions)
    qf_losses = (qf_values - next_q_value).pow(2).mean(-1)
    pi, log_pi = policy(b_obs, noise[1])
    frozen_qf = {name: p.detach() for name, p in qf_params.items()}
    actor_losses = (alpha[:, None] * log_pi - q(frozen_qf, b_obs, pi).min(0).values).mean(-1)
    alpha_losses = -(log_alpha.exp()[:, None] * (log_pi.detach() + target_entropy)).mean(-1)
    total = qf_losses.sum() + actor_losses.sum() + alpha_losses.sum()
    return total, (qf_losses, qf_values, actor_losses, alpha, alpha_losses, log_pi)


def adam_step(params: list[torch.Tensor], grads: list[torch.Tensor], state: dict) -> None:
    """torch.optim.Adam's step (eps outside the square root, as optax's too), in place, on the
    moments and step count of `state` (adam_state): as foreach ops, so that it compiles with the
    rest of the update into one function."""
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


# torch.func.grad ignores an outer no_grad; nothing else here needs autograd's records (and,
# compiled, AOTAutograd then makes an inference graph: no autograd wrapper around each call).
@torch.no_grad()
def sac_update(learner: dict, batch: tuple[torch.Tensor, ...], noise: torch.Tensor,
               actor: Actor, qf: TwinQ, gamma: float, tau: float,
               target_entropy: float) -> tuple[torch.Tensor, ...]:
    """One gradient step of every seed's twin critics, actor and temperature, and the critics'
    Polyak-averaged targets, in place on the tensors of `learner` (learner_tensors): a function of
    tensors only (the modules lend their forward passes), so that it compiles whole, once.

    As HumanoidBench's jaxrl_m: all three losses use the parameters from before this update
    (the actor is scored by the pre-update critic), and the target moves towards that critic.
    Returns the tensors that train.csv logs, per seed."""
    params = (learner["actor"], learner["qf"], learner["log_alpha"])
    grads, logs = torch.func.grad(sac_losses, has_aux=True)(
        params, learner["qf_target"], batch, noise, actor, qf, gamma, target_entropy)
    torch._foreach_lerp_(list(learner["qf_target"].values()), list(learner["qf"].values()), tau)
    for p, g, state in zip(params, grads, learner["adam"], strict=True):
        if isinstance(p, dict):
            adam_step(list(p.values()), list(g.values()), state)
        else:
            adam_step([p], [g], state)
    return logs


def adam_state(optimizer: torch.optim.Optimizer) -> dict:
    """The tensors of a torch.optim.Adam (created if it has not stepped yet, as its first step
    would) and its settings. The optimizer holds the state, so that checkpoints keep its
    state_dict; sac_update applies the step."""
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


def learner_tensors(actor: Actor, qf: TwinQ, qf_target: TwinQ, log_alpha: torch.Tensor,
                    actor_optimizer: torch.optim.Optimizer, q_optimizer: torch.optim.Optimizer,
                    alpha_optimizer: torch.optim.Optimizer) -> dict:
    """What sac_update reads and changes: the networks' parameters by name, log alpha, and the
    Adam states. The tensors are the modules' and optimizers' own: an update changes them in
    place (a checkpoint's load replaces the optimizers' tensors: call this after it)."""
    return {"actor": dict(actor.named_parameters()), "qf": dict(qf.named_parameters()),
            "qf_target": dict(qf_target.named_parameters()), "log_alpha": log_alpha,
            "adam": [adam_state(o) for o in (actor_optimizer, q_optimizer, alpha_optimizer)]}


def evaluation_round(args: Args, seed_actor: Actor, seed_qf: TwinQ, actions: dict[str, str],
                     k: int, global_step: int, wall_time: float, run_dir: Path) -> Round:
    """Seed k's evaluation round at this step, on CPU copies of its networks (seed_slice):
    training goes on while a worker runs it (eval_runner.py)."""
    seed, eval_round = args.seed + k, global_step // args.eval_interval
    videos = {"": run_dir / "videos" / f"eval_step{global_step}.mp4"} if args.capture_video \
        else {}
    if videos:
        videos[""].parent.mkdir(exist_ok=True)
    return Round(args.env_id, eval_seeds(seed, eval_round, args.eval_episodes), actions,
                 seed_actor, seed_qf if "q_best" in actions.values() else None,
                 mode_solver=args.mode_solver, shift_of=SHIFT_OF, videos=videos,
                 label=f"evaluation of seed {seed} at step {global_step}",
                 info={"seed_index": k, "global_step": global_step, "wall_time": wall_time,
                       "eval_round": eval_round})


def make_train_step(rb: ReplayBuffer, update: Callable, batch_size: int, device: torch.device,
                    graphs: bool, learner: tuple) -> Callable:
    """One gradient update (update(batch, noise)) on a fresh batch and fresh policy noise, as a
    function of nothing. With graphs and the buffer on the GPU, sampling is inside the graph; with
    the buffer in host memory, the batch is drawn there and copied into the graph's inputs."""
    noise_shape = (2, len(rb.ptr), batch_size, rb.action_dim)  # the next action's, the action's

    def update_with_noise(batch: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
        return update(batch, torch.randn(noise_shape, device=device))

    if not graphs:
        return lambda: update_with_noise(rb.sample(batch_size, device))
    if rb.obs.device.type == device.type:  # the buffer is on the run's GPU
        return cuda_graph(lambda: update_with_noise(rb.sample(batch_size, device)), learner)
    update_graph = cuda_graph(lambda *batch: update_with_noise(batch), learner)
    return lambda: update_graph(*rb.sample(batch_size, device))


def compile_update(update: Callable, learner: dict, batch: tuple[torch.Tensor, ...],
                   restore: tuple) -> Callable:
    """update(learner, batch, noise) compiled and run once on `batch` (zeros) and zero noise,
    the learner's state put back (`restore`: its modules, tensors and optimizers)."""
    noise = torch.zeros((2, *batch[1].shape), device=batch[1].device)
    return compile_at_start(update, (learner, batch, noise), restore, "the update")


def check_finite(x: np.ndarray, what: str) -> None:
    if not np.isfinite(x).all():
        raise SystemExit(f"non-finite {what} (NaN/inf): training diverged; try lower learning "
                         "rates or resume from an earlier checkpoint")


def ends_without_bootstrap(terminated: np.ndarray, truncated: np.ndarray) -> np.ndarray:
    """Whether the target of a transition drops the next state's value. HumanoidBench bootstraps
    one that is both terminated and truncated (its mask is `not terminated or truncated`)."""
    return terminated & ~truncated


def physics_blow_ups(info: dict, episode_end: np.ndarray) -> np.ndarray:
    """Which envs' last step was a physics blow-up (h1hand's info["physics_unstable"]): the
    episode ended without a real transition."""
    final = info.get("final_info", {})
    return episode_end & final.get("_physics_unstable", False) \
        & final.get("physics_unstable", False)


def train_statistics(progress: dict, losses: tuple[torch.Tensor, ...] | None, k: int) -> dict:
    """Seed k's train.csv statistics: the last update's losses (none before learning starts) and
    the training episodes that ended since the previous row (taken out of its `progress`)."""
    returns, lengths = progress["episode_returns"], progress["episode_lengths"]
    row = {"episodes": len(returns),
           "episode_return_mean": np.mean(returns) if returns else None,
           "episode_length_mean": np.mean(lengths) if lengths else None}
    returns.clear()
    lengths.clear()
    if losses is not None:
        qf_losses, qf_values, actor_losses, alpha, alpha_losses, log_pi = losses
        check_finite(qf_losses[:, k].detach().cpu().numpy(), "critic loss")
        row |= {"qf1_loss": qf_losses[0, k].item(), "qf2_loss": qf_losses[1, k].item(),
                "qf1_value": qf_values[0, k].mean().item(),
                "qf2_value": qf_values[1, k].mean().item(), "actor_loss": actor_losses[k].item(),
                "alpha": alpha[k].item(), "alpha_loss": alpha_losses[k].item(),
                "entropy": -log_pi[k].mean().item()}
    return row


def run_dirs(args: Args) -> list[Path]:
    """Each seed's run folder: --run-name with {seed} filled in, or the default name."""
    name = args.run_name or (f"{args.env_id}__{ALGORITHM}__seed{{seed}}__"
                             f"{time.strftime('%Y%m%d-%H%M%S')}")
    return [Path(args.output_dir) / name.replace("{seed}", str(args.seed + k))
            for k in range(args.num_seeds)]


def batch_run_dirs(args: Args) -> list[Path]:
    """With --resume, the folders of the batch the given one belongs to, each checked before
    anything is written (run_folder.py); else fresh folders, none of which may hold a run."""
    if args.resume is None:
        dirs = run_dirs(args)
        for run_dir in dirs:
            if (run_dir / "config.json").exists():
                fail(f"{run_dir} already holds a run; continue it with --resume {run_dir} or "
                     "choose another --run-name")
        return dirs
    return resume_batch_dirs(Path(args.resume), ALGORITHM)


if __name__ == "__main__":
    args = parse_args()
    stop = StopRequest()  # from the start, so a signal during setup also ends in exit code 3
    torch.set_num_threads(args.torch_threads)
    dirs = batch_run_dirs(args)
    seeds = [args.seed + k for k in range(args.num_seeds)]
    if all((d / "done.json").exists() for d in dirs):
        print(f"{', '.join(map(str, dirs))}: already finished (done.json); nothing to do")
        sys.exit(0)

    random.seed(args.seed)
    np.random.seed(args.seed)  # noqa: NPY002
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    print(f"device: {device}" + (" (no CUDA GPU found)" if args.cuda and device.type == "cpu"
                                 else ""), flush=True)

    space = make_env(args.env_id).action_space  # checks the id and the spaces
    spaces = [copy.deepcopy(space) for _ in seeds]  # the random start actions: one per seed
    for space, seed in zip(spaces, seeds, strict=True):
        space.seed(seed)
    envs = make_vector_env(args.env_id, args.num_seeds)
    # However this process exits: its env workers ignore SIGTERM, so multiprocessing's own exit
    # handler (terminate, then join) would wait for them forever.
    atexit.register(envs.close)
    obs_dim, action_dim = envs.single_observation_space.shape[0], spaces[0].shape[0]

    # Each seed's networks are initialised from its own generator, whatever the batch.
    generators = [torch.Generator().manual_seed(seed) for seed in seeds]
    actor = Actor(obs_dim, args.hidden_sizes, spaces[0], args.log_std_min, args.log_std_max,
                  args.num_seeds, generators).to(device)
    qf = TwinQ(obs_dim, action_dim, args.hidden_sizes, args.num_seeds, generators).to(device)
    qf_target = copy.deepcopy(qf)
    # The optimizers hold Adam's state (checkpoints keep their state_dict); sac_update steps it.
    # fused: a loaded state_dict puts the step counts on the parameters' device, as the update,
    # one function (a CUDA graph on a GPU), needs.
    adam = functools.partial(torch.optim.Adam, fused=True, capturable=device.type == "cuda")
    q_optimizer = adam(qf.parameters(), lr=args.q_lr)
    actor_optimizer = adam(actor.parameters(), lr=args.policy_lr)
    target_entropy = -args.target_entropy_scale * action_dim
    log_alpha = torch.full((args.num_seeds,), float(np.log(args.alpha_init)), device=device,
                           requires_grad=True)
    alpha_optimizer = adam([log_alpha], lr=args.alpha_lr)
    optimizers = (actor_optimizer, q_optimizer, alpha_optimizer)
    rb = ReplayBuffer(args.num_seeds, args.buffer_size, obs_dim, action_dim,
                      device if args.gpu_buffer else torch.device("cpu"))

    actions = eval_actions(args)
    eval_header = ["global_step", "wall_time", "eval_round",
                   *eval_columns(actions, shift=SHIFT_OF is not None)]

    # The batch's folders: fresh, or resumed from their checkpoints, or restarted if they have
    # none yet. Every folder is locked and checked before anything in any of them is written.
    locks = lock_run_folders(dirs)
    ckpts = read_batch_checkpoints(dirs) if args.resume is not None else None
    if ckpts is not None:
        wanted = {k: v for k, v in dataclasses.asdict(args).items() if k not in RUNTIME_FIELDS}
        for run_dir, ckpt in zip(dirs, ckpts, strict=True):
            if {k: v for k, v in ckpt["args"].items() if k not in RUNTIME_FIELDS} != wanted:
                fail(f"{run_dir / 'checkpoint.pt'} was made with other arguments than "
                     f"{run_dir / 'config.json'}; the run folder is inconsistent")
            check_csv(run_dir / "eval.csv", eval_header)
            check_csv(run_dir / "train.csv", list(TRAIN_COLUMNS))
        for module, key in ((actor, "actor"), (qf, "qf"), (qf_target, "qf_target")):
            load_seed_states(module, [c[key] for c in ckpts])
        for optimizer, key in ((q_optimizer, "q_optimizer"), (actor_optimizer, "actor_optimizer"),
                               (alpha_optimizer, "alpha_optimizer")):
            load_optimizer_seed_states(optimizer, [c[key] for c in ckpts])
        for group in (g for optimizer in optimizers for g in optimizer.param_groups):
            group["capturable"] = device.type == "cuda"  # the checkpoint's is its device's
        with torch.no_grad():
            log_alpha.copy_(torch.cat([c["log_alpha"] for c in ckpts]))
        for k, ckpt in enumerate(ckpts):
            rb.load_seed_state_dict(k, ckpt["buffer"])
            spaces[k].np_random.bit_generator.state = ckpt["rng"]["action_space"]
        set_rng_states(ckpts[0]["rng"], device)
        global_step, elapsed = ckpts[0]["global_step"], ckpts[0]["elapsed"]
        progress = [c["progress"] for c in ckpts]
        # Every env's episode so far, replayed: the checkpoint may fall mid-episode.
        envs.reset(seed=seeds)
        envs.set_attr("record", [c["rng"]["episode"] for c in ckpts])
        obs = np.stack(envs.call("replay"))
        print(f"resuming {', '.join(map(str, dirs))} at step {global_step}", flush=True)
    else:
        global_step, elapsed = 0, 0.0
        progress = [{"episode_returns": [], "episode_lengths": [], "last_eval": None,
                     "episode_return": 0.0, "episode_length": 0} for _ in seeds]
        batch = {"first_seed": args.seed, "num_seeds": args.num_seeds,
                 "run_dirs": [d.name for d in dirs]}
        for run_dir, seed in zip(dirs, seeds, strict=True):
            for old in run_dir.glob("events.out.tfevents.*"):  # a restart from step 0
                old.unlink()
            config = run_metadata(dataclasses.replace(args, seed=seed), obs_dim, action_dim,
                                  ALGORITHM, Path(__file__).name)
            atomic_write(run_dir / "config.json", lambda tmp, c=config: tmp.write_text(
                json.dumps(c | {"batch": batch}, indent=2)))
        obs, _ = envs.reset(seed=seeds)
    for lock in locks:
        record_holder(lock)
    keep = global_step if args.resume is not None else None
    graphs = device.type == "cuda" and args.cudagraphs
    graphed = cuda_graph if graphs else (lambda fn, restore=(): fn)
    # Acting: a sampled action per seed from its observation, (K, obs) -> (K, A).
    act = torch.no_grad()(lambda obs, noise: actor.squash(*actor(obs[:, None]), noise)[0][:, 0])
    noise_shape = (args.num_seeds, 1, action_dim)
    if args.compile:
        act = compile_at_start(act, (torch.zeros((args.num_seeds, obs_dim), device=device),
                                     torch.zeros(noise_shape, device=device)), (), "acting")
    train_action = graphed(lambda obs: act(obs, torch.randn(noise_shape, device=device)))
    learner = learner_tensors(actor, qf, qf_target, log_alpha, *optimizers)
    update = functools.partial(sac_update, actor=actor, qf=qf, gamma=args.gamma, tau=args.tau,
                               target_entropy=target_entropy)
    if args.compile:
        update = compile_update(update, learner, rb.zero_batch(args.batch_size, device),
                                (actor, qf, qf_target, log_alpha, *optimizers))
    train_step = make_train_step(rb, lambda batch, noise: update(learner, batch, noise),
                                 args.batch_size, device, graphs,
                                 (actor, qf, qf_target, log_alpha, *optimizers))
    logs = []  # per seed: eval.csv and train.csv writers, TensorBoard, W&B
    for run_dir, seed in zip(dirs, seeds, strict=True):
        tb = SummaryWriter(run_dir, purge_step=global_step + 1 if ckpts is not None else None)
        if ckpts is None:
            tb.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(
                f"|{k}|{v}|" for k, v in dataclasses.asdict(args).items()))
        logs.append({"eval": open_csv(run_dir / "eval.csv", eval_header, keep),
                     "train": open_csv(run_dir / "train.csv", list(TRAIN_COLUMNS), keep),
                     "tb": tb, "tracker": start_tracking(dataclasses.replace(args, seed=seed),
                                                         run_dir, ALGORITHM)})
    # Evaluation rounds that a stop checkpointed before they finished: rerun first, below.
    pending = [c.get("pending_rounds", []) for c in ckpts] if ckpts is not None else []
    del ckpts

    def log_evaluation(round_: Round, result: dict) -> None:
        """An evaluation round's eval.csv row; EvalPool calls this in step order."""
        row, k = dict(round_.info), round_.info["seed_index"]
        del row["seed_index"]
        row |= round_row(result, actions)
        write_row(*logs[k]["eval"], logs[k]["tb"], logs[k]["tracker"], "eval", row,
                  round_.videos.get(""))
        progress[k]["last_eval"] = (row["global_step"], row["return_mean"])

    # Training takes a core, and with K > 1 so does each env's worker process.
    busy = 1 + (args.num_seeds if args.num_seeds > 1 else 0)
    eval_pool = EvalPool(default_workers(busy) if args.eval_workers is None else args.eval_workers,
                         log_evaluation, rounds_per_step=args.num_seeds)
    for k, rounds in enumerate(pending):
        for state in rounds:
            seed_actor, seed_qf = seed_slice(actor, k).cpu(), seed_slice(qf, k).cpu()
            seed_actor.load_state_dict(state["actor"])
            if state["qf"] is not None:
                seed_qf.load_state_dict(state["qf"])
            eval_pool.submit(evaluation_round(args, seed_actor, seed_qf, actions, k,
                                              state["global_step"], state["wall_time"], dirs[k]))
    session_start, row_start, row_step = time.time(), time.time(), global_step
    losses = None
    while global_step < args.total_timesteps:
        if global_step < args.learning_starts:
            action = np.stack([space.sample() for space in spaces])
        else:
            action = train_action(torch.as_tensor(obs, dtype=torch.float32, device=device))
            action = action.cpu().numpy()
            check_finite(action, "action")
        next_obs, reward, terminated, truncated, info = envs.step(action)
        global_step += 1
        episode_end = terminated | truncated
        final_obs = next_obs.copy()  # an ended episode's env has already reset: its final obs
        for k in np.flatnonzero(episode_end):
            final_obs[k] = info["final_obs"][k]
        rb.add(obs, action, reward, ends_without_bootstrap(terminated, truncated), final_obs,
               episode_end, physics_blow_ups(info, episode_end))
        obs = next_obs
        for k, seed_progress in enumerate(progress):
            seed_progress["episode_return"] += float(reward[k])
            seed_progress["episode_length"] += 1
            if episode_end[k]:
                seed_progress["episode_returns"].append(seed_progress["episode_return"])
                seed_progress["episode_lengths"].append(seed_progress["episode_length"])
                seed_progress["episode_return"], seed_progress["episode_length"] = 0.0, 0

        if global_step >= args.learning_starts:
            losses = train_step()

        if global_step % args.log_interval == 0:
            now = time.time()
            for k, log in enumerate(logs):
                row = {"global_step": global_step, "wall_time": elapsed + now - session_start,
                       "sps": (global_step - row_step) / (now - row_start),
                       **train_statistics(progress[k], losses, k)}
                write_row(*log["train"], log["tb"], log["tracker"], "train", row)
            row_start, row_step = now, global_step

        if global_step % args.eval_interval == 0:
            wall_time = elapsed + time.time() - session_start
            for k, run_dir in enumerate(dirs):
                eval_pool.submit(evaluation_round(
                    args, seed_slice(actor, k).cpu(), seed_slice(qf, k).cpu(), actions, k,
                    global_step, wall_time, run_dir))
        eval_pool.poll()

        if global_step % args.print_interval == 0:
            last = [p["last_eval"] for p in progress if p["last_eval"] is not None]
            print(f"step {global_step:,}/{args.total_timesteps:,} | "
                  f"{global_step / (elapsed + time.time() - session_start):.0f} SPS per seed | "
                  + (f"last eval {np.mean([r for _, r in last]):.1f}"
                     + (f" (mean over {len(last)} seeds)" if len(last) > 1 else "")
                     + f" at step {last[0][0]:,}" if last else "no eval yet"),
                  flush=True)

        if stop.requested or (args.checkpoint_interval > 0
                              and global_step % args.checkpoint_interval == 0):
            # A stop checkpoints at once, recording the rounds still running (the resumed run
            # reruns them), so that it needs seconds of grace; otherwise every round before
            # the checkpoint is in eval.csv first.
            unfinished = eval_pool.abandon() if stop.requested else []
            eval_pool.drain()
            episodes = envs.get_attr("record")
            rng = rng_states(device)
            save_batch_checkpoint(dirs, [{
                "args": dataclasses.asdict(args), "global_step": global_step,
                "elapsed": elapsed + time.time() - session_start, "progress": progress[k],
                "actor": seed_slice(actor, k).state_dict(), "qf": seed_slice(qf, k).state_dict(),
                "qf_target": seed_slice(qf_target, k).state_dict(),
                "log_alpha": log_alpha.detach()[k:k + 1].clone(),
                "q_optimizer": optimizer_seed_state(q_optimizer, k),
                "actor_optimizer": optimizer_seed_state(actor_optimizer, k),
                "alpha_optimizer": optimizer_seed_state(alpha_optimizer, k),
                "buffer": rb.seed_state_dict(k),
                "rng": rng | {"action_space": spaces[k].np_random.bit_generator.state,
                              "episode": episode_state(episodes[k], action_dim)},
                "pending_rounds": [pending_round_state(r) for r in unfinished
                                   if r.info["seed_index"] == k]}
                for k in range(args.num_seeds)])
            if stop.requested:
                for log in logs:
                    log["tb"].close()
                    if log["tracker"] is not None:
                        log["tracker"].finish()
                print(f"interrupted at step {global_step}; resume with --resume {dirs[0]}",
                      flush=True)
                sys.exit(INTERRUPTED_EXIT_CODE)

    eval_pool.drain()
    eval_pool.close()
    wall_time = elapsed + time.time() - session_start
    for k, (run_dir, log) in enumerate(zip(dirs, logs, strict=True)):
        atomic_write(run_dir / "final_model.pt", lambda tmp, k=k: torch.save(on_cpu(
            {"actor": seed_slice(actor, k).state_dict(), "qf": seed_slice(qf, k).state_dict(),
             "config": {f: getattr(args, f) for f in MODEL_FIELDS}}), tmp))
        log["tb"].close()
        if log["tracker"] is not None:
            log["tracker"].finish()
        for f, _ in (log["eval"], log["train"]):
            f.close()
        atomic_write(run_dir / "done.json", lambda tmp: tmp.write_text(json.dumps(
            {"global_step": global_step, "wall_time": wall_time})))
    print(f"finished {global_step} steps in {wall_time:.0f} s: "
          f"{', '.join(map(str, dirs))}", flush=True)
