"""Evaluation rounds as jobs, off the training path: sac_standard.py, sac_corrected.py and
evaluate.py all evaluate through this module.

A `Round` is everything one evaluation round needs and nothing that training still changes: CPU
copies of the actor (and of the critic, for `q_best`), the reset seeds, and the evaluation
actions by eval.csv column prefix. `run_round` steps every episode of every evaluation action in
lockstep: one actor call per action per step over all of that action's episodes, finished ones
kept in place (so every call has the same batch shape, and a row's numbers never depend on when
other episodes ended) and masked. Episode k of every action resets with the same seed: the
comparison between actions is paired. An episode whose start state repeats an earlier one's
(identical physics and task state after reset, on an env whose steps draw no randomness) under a
deterministic action is that episode again: it gets the first one's row without its env being
stepped (the actor still sees every row, so the first episode's numbers are as before; BLAS may
round equal rows of a batch differently by position, which made such copies differ in their last
bits, then more as the physics amplified it). On a task that resets without noise
(h1hand-bookshelf_simple-v0) a round runs one episode per action, not ten.

`EvalPool` runs rounds in worker processes while training goes on, and hands the results back in
submission order. With 0 workers it runs each round at once, in-process: one code path. A round
always runs on one CPU thread, wherever it runs, so its numbers are the same with any number of
workers: on a GPU node the env, not the actor, is the cost of an evaluation step.

Evaluation actions, each in (-1, 1)^A before the env's scaling (mode_search.py):
- "mode": the mode of the squashed Gaussian (Corrected SAC).
- "tanh_mu": tanh(mu); tanh is monotone, so this is the squashed policy's per-dimension median
  (standard SAC).
- "mean": E[tanh(u)], the squashed policy's mean.
- "q_best": at each state, whichever of tanh(mu), the mode and the mean has the highest
  min(Q1, Q2) under the run's own critic (one batched critic call; ties go to tanh(mu)).
- "sample": a stochastic action, its noise from a generator seeded by the episode's reset seed.
"""

from __future__ import annotations

import collections
import concurrent.futures
import concurrent.futures.process  # BrokenProcessPool, also with 0 workers
import ctypes
import multiprocessing
import os
import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

import humanoid_envs  # noqa: F401  (registers the h1hand tasks in worker processes too)
from mode_search import mean_action, mode_action

ACTIONS = ("mode", "tanh_mu", "mean", "q_best", "sample")
# q_best's candidates, tanh(mu) first: argmax keeps the first maximum, so ties go to it.
Q_BEST_CANDIDATES = ("tanh_mu", "mode", "mean")
EVAL_STATS = ("return_mean", "return_std", "return_min", "return_max", "length_mean",
              "success_rate")
SHIFT_COLUMNS = ("mode_shift_abs_mean", "mode_shift_abs_sum", "sigma_mean", "bimodal_fraction")


class EvalError(Exception):
    """A round that cannot finish (a NaN action, say): its message is one line for the user."""


@dataclass
class Round:
    """One evaluation round, self-contained: it can be pickled to a worker process."""

    env_id: str
    seeds: list[int]
    """the reset seed of each episode, shared by every evaluation action"""
    actions: dict[str, str | Callable]
    """eval.csv column prefix -> evaluation action: one of ACTIONS, or a script's function of
    that name, (mu, log sigma, mode solver) -> action in (-1, 1)^A"""
    actor: nn.Module
    """a CPU copy: forward(obs) -> (mu, log sigma) before the tanh; scale(y) -> env action"""
    critic: nn.Module | None = None
    """a CPU copy, for q_best: (obs, env action) -> Q1 and Q2, shape (2, batch)"""
    mode_solver: str = "exact"
    reset_noise: float | None = None
    """the half-width of the uniform noise on qpos at each reset (h1hand's reset option
    qpos_noise; None: the task's own), so that a task that resets without noise can be evaluated
    from distinct starts; episode k of every action still starts from the same state"""
    shift_of: str | None = None
    """the prefix whose visited states give the mode-vs-tanh(mu) shift statistics"""
    videos: dict[str, Path] = field(default_factory=dict)
    """prefix -> where to write that action's first episode as an MP4"""
    label: str = "evaluation"
    """where the round comes from (e.g. "step 20000"), for error messages"""
    info: dict = field(default_factory=dict)
    """anything the submitter wants back with the result (not used by the round)"""


def eval_seeds(seed: int, eval_round: int, episodes: int) -> list[int]:
    """Reset seeds from (run seed, round, episode): every run with this seed sees these starts."""
    return [int(np.random.SeedSequence([seed, eval_round, e]).generate_state(1)[0])
            for e in range(episodes)]


def q_best_choice(obs: torch.Tensor, candidates: dict[str, torch.Tensor], actor: nn.Module,
                  critic: nn.Module) -> torch.Tensor:
    """For each row, the index into Q_BEST_CANDIDATES of the candidate with the highest
    min(Q1, Q2); one critic call over all candidates stacked."""
    ys = torch.stack([candidates[name] for name in Q_BEST_CANDIDATES])  # (C, batch, A)
    c, n = ys.shape[:2]
    q = critic(obs.repeat(c, 1), actor.scale(ys.reshape(c * n, -1))).min(0).values
    return q.reshape(c, n).argmax(0)


def action_name(action: str | Callable) -> str:
    """An evaluation action's name: a script's own action is a function named after it."""
    return action if isinstance(action, str) else action.__name__


def shift_measured_at(actions: dict[str, str | Callable]) -> str | None:
    """The prefix whose visited states give the shift statistics: a run's own evaluation action
    (prefix "") when it is the mode, as sac_corrected.py's; None otherwise (no shift columns)."""
    return "" if "" in actions and action_name(actions[""]) == "mode" else None


def select_actions(name: str | Callable, mu: torch.Tensor, log_std: torch.Tensor,
                   obs: torch.Tensor, round_: Round, generators: list[torch.Generator]
                   ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The squashed actions (batch, A) of one evaluation action, and for q_best its choices."""
    if callable(name):
        return name(mu, log_std, round_.mode_solver), None
    if name == "tanh_mu":
        return torch.tanh(mu), None
    if name == "mode":
        return mode_action(mu, log_std, round_.mode_solver), None
    if name == "mean":
        return mean_action(mu, log_std), None
    if name == "sample":
        noise = torch.stack([torch.randn(mu.shape[1], generator=g) for g in generators])
        return torch.tanh(mu + noise * log_std.exp()), None
    candidates = {"tanh_mu": torch.tanh(mu), "mode": mode_action(mu, log_std, round_.mode_solver),
                  "mean": mean_action(mu, log_std)}
    choice = q_best_choice(obs, candidates, round_.actor, round_.critic)
    ys = torch.stack([candidates[c] for c in Q_BEST_CANDIDATES])
    return ys.gather(0, choice[None, :, None].expand(1, *mu.shape))[0], choice


def shift_statistics(mu: torch.Tensor, log_std: torch.Tensor, solver: str) -> dict[str, float]:
    """How far the mode is from tanh(mu) at the given states (rows), and how wide sigma is:
    2 sigma^2 > 1 is the regime where the squashed density can have two modes."""
    shift = (mode_action(mu, log_std, solver) - torch.tanh(mu)).abs()
    sigma = log_std.exp()
    return {"mode_shift_abs_mean": shift.mean().item(),
            "mode_shift_abs_sum": shift.sum(1).mean().item(), "sigma_mean": sigma.mean().item(),
            "bimodal_fraction": (2 * sigma**2 > 1).float().mean().item()}


_ENVS: dict[tuple[str, bool], list[gym.Env]] = {}


def cached_envs(env_id: str, count: int, render: bool = False) -> list[gym.Env]:
    """count envs of env_id, made once per process: a round resets each one with its seed, so a
    reused env starts exactly as a new one would."""
    envs = _ENVS.setdefault((env_id, render), [])
    while len(envs) < count:
        envs.append(gym.make(env_id, **({"render_mode": "rgb_array"} if render else {})))
    return envs[:count]


@torch.no_grad()
def run_round(round_: Round) -> dict:
    """Every episode of every evaluation action of the round, stepped in lockstep.

    Returns, per prefix, each episode's return, length, success (None where the env reports
    none) and whether a physics blow-up ended it ("unstable": info["physics_unstable"]) and, for
    q_best, the share of states at which each candidate was chosen; under "shift", the shift
    statistics at the states the `shift_of` prefix visited ("shift_states" of them)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the same numbers in-process and in a worker
    try:
        return _run_round(round_)
    finally:
        torch.set_num_threads(threads)


def start_key(env: gym.Env) -> bytes | None:
    """The env's state after reset, if the env can tell it and its steps draw no randomness
    (H1HandEnv.start_state); None where either is unknown, which makes the episode distinct."""
    start_state = getattr(env.unwrapped, "start_state", None)
    return None if start_state is None else start_state()


def first_with_same_start(envs: list[gym.Env]) -> np.ndarray:
    """For each freshly reset env, the index of the first env with the same start state (its
    own index when it is the first, or when its start state is unknown)."""
    firsts: dict[bytes, int] = {}
    same = np.arange(len(envs))
    for k, env in enumerate(envs):
        key = start_key(env)
        if key is not None:
            same[k] = firsts.setdefault(key, k)
    return same


def _run_round(round_: Round) -> dict:
    n, prefixes = len(round_.seeds), list(round_.actions)
    envs = cached_envs(round_.env_id, n * len(prefixes))
    episodes = {p: envs[i * n:(i + 1) * n] for i, p in enumerate(prefixes)}
    renders = cached_envs(round_.env_id, len(round_.videos), render=True)
    for p, env in zip(round_.videos, renders, strict=True):  # first episodes that are filmed
        episodes[p] = [env, *episodes[p][1:]]
    options = None if round_.reset_noise is None else {"qpos_noise": round_.reset_noise}
    obs = {p: np.stack([env.reset(seed=s, options=options)[0]
                        for env, s in zip(episodes[p], round_.seeds, strict=True)])
           for p in prefixes}
    # Each episode follows the first with its start state (every action resets its episodes
    # with the same seeds); a "sample" action's noise differs per episode, so none of its
    # episodes follows another.
    starts = first_with_same_start(episodes[prefixes[0]])
    same = {p: np.arange(n) if round_.actions[p] == "sample" else starts for p in prefixes}
    done = {p: np.zeros(n, bool) for p in prefixes}
    returns = {p: np.zeros(n) for p in prefixes}
    lengths = {p: np.zeros(n, np.int64) for p in prefixes}
    successes: dict[str, list] = {p: [None] * n for p in prefixes}
    # Whether the episode ended on a physics blow-up (h1hand truncates it then): otherwise such
    # an end reads as an ordinary short episode, whichever action caused it.
    unstable = {p: [False] * n for p in prefixes}
    ends: dict[str, list] = {p: [""] * n for p in prefixes}
    chosen = {p: np.zeros(len(Q_BEST_CANDIDATES), np.int64) for p in prefixes}
    visited: list[tuple[torch.Tensor, torch.Tensor]] = []
    # "sample" draws each episode's noise from a generator seeded by its reset seed.
    generators = [torch.Generator().manual_seed(s) for s in round_.seeds]
    frames: dict[str, list] = {p: [] for p in round_.videos}
    while not all(d.all() for d in done.values()):
        for p in prefixes:
            live = ~done[p]
            if not live.any():
                continue
            obs_t = torch.as_tensor(obs[p], dtype=torch.float32)
            mu, log_std = round_.actor(obs_t)
            y, choice = select_actions(round_.actions[p], mu, log_std, obs_t, round_, generators)
            actions = round_.actor.scale(y).numpy()
            bad = np.flatnonzero(live & ~np.isfinite(actions).all(1))
            if bad.size:
                k = int(bad[0])
                raise EvalError(
                    f"{round_.label}: the evaluation action {action_name(round_.actions[p])!r} "
                    "is NaN/inf in "
                    f"episode {k} (reset seed {round_.seeds[k]}); the actor diverged: resume from "
                    "an earlier checkpoint or lower the learning rates")
            if choice is not None:
                chosen[p] += np.bincount(choice.numpy()[live], minlength=len(Q_BEST_CANDIDATES))
            if p == round_.shift_of:
                visited.append((mu[live], log_std[live]))
            first = same[p] == np.arange(n)
            for k in np.flatnonzero(live & first):
                env = episodes[p][k]
                if k == 0 and p in frames:
                    frames[p].append(env.render())
                obs[p][k], reward, terminated, truncated, info = env.step(actions[k])
                returns[p][k] += float(reward)
                lengths[p][k] += 1
                if terminated or truncated:
                    done[p][k] = True
                    successes[p][k] = info.get("success")
                    unstable[p][k] = bool(info.get("physics_unstable", False))
                    ends[p][k] = episode_end(terminated, info)
            # A follower is its first episode again: same rows in the next actor call, same
            # numbers, ending together.
            for k in np.flatnonzero(live & ~first):
                j = same[p][k]
                obs[p][k], returns[p][k], lengths[p][k] = obs[p][j], returns[p][j], lengths[p][j]
                done[p][k], successes[p][k] = done[p][j], successes[p][j]
                unstable[p][k], ends[p][k] = unstable[p][j], ends[p][j]
    for p, path in round_.videos.items():
        import imageio  # only for videos

        imageio.mimsave(path, frames[p], fps=episodes[p][0].metadata.get("render_fps", 30))
    result: dict = {p: {"returns": returns[p].tolist(), "lengths": lengths[p].tolist(),
                        "successes": successes[p], "unstable": unstable[p], "ends": ends[p]}
                      for p in prefixes}
    # Distinct start states: how many episodes each deterministic action stepped.
    result["distinct_episodes"] = len(set(starts.tolist()))
    for p in prefixes:
        if round_.actions[p] == "q_best":
            shares = chosen[p] / max(chosen[p].sum(), 1)
            result[p]["shares"] = dict(zip(Q_BEST_CANDIDATES, shares.tolist(), strict=True))
    if round_.shift_of is not None:
        mu, log_std = (torch.cat(t) for t in zip(*visited, strict=True))
        result["shift"] = shift_statistics(mu, log_std, round_.mode_solver)
        result["shift_states"] = len(mu)  # to pool the statistics of several rounds
    return result


def episode_end(terminated: bool, info: dict) -> str:
    """Why an episode ended: the task's reason where it terminated (h1hand: "fell", "dropped",
    "success"; "terminated" where the env gives none), "blow_up" for a physics blow-up, else
    "time_limit"."""
    if terminated:
        return info.get("termination", "terminated")
    return "blow_up" if info.get("physics_unstable", False) else "time_limit"


def round_statistics(result: dict, prefix: str) -> dict:
    """eval.csv's statistics of one prefix of a round (success_rate None where the env reports
    none), with q_best's choice shares as q_best_share_<candidate>."""
    returns, successes = result[prefix]["returns"], result[prefix]["successes"]
    stats = {"return_mean": np.mean(returns), "return_std": np.std(returns),
             "return_min": np.min(returns), "return_max": np.max(returns),
             "length_mean": np.mean(result[prefix]["lengths"]),
             "success_rate": None if None in successes else np.mean(successes)}
    row = {prefix + k: None if v is None else float(v) for k, v in stats.items()}
    for name, share in result[prefix].get("shares", {}).items():
        row[f"{prefix}share_{name}"] = share
    return row


def round_row(result: dict, actions: dict[str, str]) -> dict:
    """eval.csv's statistics of a round (eval_columns): how many distinct episodes it ran, each
    prefix's statistics, and the shift statistics where the round measured them."""
    row = {"distinct_episodes": result["distinct_episodes"]}
    for prefix in actions:
        row |= round_statistics(result, prefix)
    return row | result.get("shift", {})


def eval_columns(actions: dict[str, str], shift: bool) -> list[str]:
    """The statistics columns of eval.csv for these evaluation actions (see round_row)."""
    columns = ["distinct_episodes", *(p + s for p in actions for s in EVAL_STATS)]
    columns += [f"{p}share_{c}" for p, a in actions.items() if a == "q_best"
                for c in Q_BEST_CANDIDATES]
    return columns + (list(SHIFT_COLUMNS) if shift else [])


# --- the pool ---------------------------------------------------------------------------------
def default_workers() -> int:
    """The cores that training leaves free: all but one (at least one worker)."""
    return max(1, len(os.sched_getaffinity(0)) - 1)


def _init_worker() -> None:
    """A worker evaluates on one thread, leaves stopping to its training process (which finishes
    the pending rounds before a checkpoint) and dies with it."""
    torch.set_num_threads(1)
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
        signal.signal(s, signal.SIG_IGN)
    try:  # Linux: the kernel kills this worker when its parent dies, SIGKILL included
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class EvalPool:
    """Rounds run by `workers` processes; `on_done(round, result)` is called in submission order.

    At most `max_pending` rounds are in flight, by default two per worker: submitting one more
    first waits for the oldest, so evaluation cannot fall behind training without limit. With 0
    workers, submit runs the round at once. A round that fails, for any reason, ends the run with
    one line naming the round and the cause (SystemExit), the pool shut down."""

    def __init__(self, workers: int, on_done: Callable[[Round, dict], None],
                 max_pending: int | None = None):
        self.workers, self.on_done = workers, on_done
        self.max_pending = max_pending or 2 * max(workers, 1)
        self.pending: collections.deque = collections.deque()
        self.executor = None if workers == 0 else concurrent.futures.ProcessPoolExecutor(
            workers, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker)

    def submit(self, round_: Round) -> None:
        if self.executor is None:
            self.on_done(round_, self._result(lambda: run_round(round_), round_))
            return
        while len(self.pending) >= self.max_pending:
            self._finish_oldest()
        self.pending.append((self.executor.submit(run_round, round_), round_))

    def poll(self) -> None:
        """Hands back every finished round at the head of the queue (never waits)."""
        while self.pending and self.pending[0][0].done():
            self._finish_oldest()

    def drain(self) -> None:
        """Waits for every pending round: after this, every submitted round is handed back."""
        while self.pending:
            self._finish_oldest()

    def abandon(self) -> list[Round]:
        """Stops at once: the rounds not yet handed back, in submission order, and the workers
        killed without waiting for them (a stop under a short grace period records the rounds in
        its checkpoint, and the resumed run reruns them: a round is a pure function)."""
        rounds = [round_ for _, round_ in self.pending]
        self.pending.clear()
        if self.executor is not None:
            # Workers ignore SIGTERM (the training process decides), and shutdown(wait=False)
            # would still let the interpreter's exit wait for their running rounds.
            for process in list(self.executor._processes.values()):
                process.kill()
            self.executor.shutdown(wait=False, cancel_futures=True)
        return rounds

    def close(self) -> None:
        if self.executor is not None:
            self.executor.shutdown(wait=True, cancel_futures=True)

    def _finish_oldest(self) -> None:
        future, round_ = self.pending.popleft()
        self.on_done(round_, self._result(future.result, round_))

    def _result(self, get: Callable[[], dict], round_: Round) -> dict:
        try:
            return get()
        except EvalError as error:
            self._abort(str(error))
        except concurrent.futures.process.BrokenProcessPool as error:
            self._abort(f"{round_.label}: an evaluation worker died ({error}); the last "
                        "checkpoint is intact: resume from it")
        except Exception as error:  # the env's, a video writer's: the round can't finish
            cause = str(error).splitlines()[0] if str(error) else ""
            self._abort(f"{round_.label} failed: {type(error).__name__}: {cause}; the last "
                        "checkpoint is intact: fix the cause and resume from it")

    def _abort(self, message: str):
        if self.executor is not None:
            self.executor.shutdown(wait=False, cancel_futures=True)
        raise SystemExit(message)
