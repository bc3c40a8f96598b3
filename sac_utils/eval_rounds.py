"""Evaluation rounds as jobs, off the training path (the SAC scripts and evaluate.py).

A `Round` holds all one round needs; `run_round` steps each action's episodes in lockstep, one
actor call per step, finished episodes kept in the batch and masked, so a row's numbers never
depend on when others ended. Episode k of every action resets with the same seed (paired). An
episode whose start state repeats an earlier one's under a deterministic action copies its row
unstepped (BLAS rounds equal rows by position, and chaos amplifies that). A round runs on one
thread anywhere, so its numbers do not depend on `EvalPool`'s worker count.

Actions, in (-1, 1)^A before the env's scaling (mode_search.py): "mode" (Corrected SAC),
"tanh_mu" (the per-dimension median: standard SAC), "mean" (E[tanh(u)]), "q_best" (whichever of
those three has the highest min(Q1, Q2); ties to tanh(mu)), "sample" (noise seeded per episode).
"""

from __future__ import annotations

import collections
import concurrent.futures
import concurrent.futures.process  # BrokenProcessPool, also with 0 workers
import ctypes
import multiprocessing
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
    seeds: list[int]  # each episode's reset seed, shared by every action
    actions: dict[str, str | Callable]  # prefix -> one of ACTIONS, or a script's function of it
    actor: nn.Module  # forward(obs) -> (mu, log sigma); scale(y) -> env action
    critic: nn.Module | None = None  # for q_best: (obs, env action) -> (2, batch)
    mode_solver: str = "exact"
    reset_noise: float | None = None  # h1hand's qpos_noise at each reset (None: the task's)
    shift_of: str | None = None  # the prefix whose visited states give the shift statistics
    videos: dict[str, Path] = field(default_factory=dict)  # prefix -> its first episode's MP4
    label: str = "evaluation"  # where the round comes from, for error messages
    info: dict = field(default_factory=dict)  # handed back with the result, unused


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
    """One evaluation action's squashed actions (batch, A), and q_best's choices."""
    if callable(name):
        return name(mu, log_std, round_.mode_solver), None
    if name == "sample":
        noise = torch.stack([torch.randn(mu.shape[1], generator=g) for g in generators])
        return torch.tanh(mu + noise * log_std.exp()), None
    fixed = {"tanh_mu": lambda: torch.tanh(mu), "mean": lambda: mean_action(mu, log_std),
             "mode": lambda: mode_action(mu, log_std, round_.mode_solver)}
    if name != "q_best":
        return fixed[name](), None
    candidates = {c: fixed[c]() for c in Q_BEST_CANDIDATES}
    choice = q_best_choice(obs, candidates, round_.actor, round_.critic)
    ys = torch.stack(list(candidates.values()))
    return ys.gather(0, choice[None, :, None].expand(1, *mu.shape))[0], choice


def shift_statistics(mu: torch.Tensor, log_std: torch.Tensor, solver: str) -> dict[str, float]:
    """How far the mode is from tanh(mu) at these states, and sigma (2 sigma^2 > 1: the
    squashed density can have two modes)."""
    shift = (mode_action(mu, log_std, solver) - torch.tanh(mu)).abs()
    sigma = log_std.exp()
    return {"mode_shift_abs_mean": shift.mean().item(),
            "mode_shift_abs_sum": shift.sum(1).mean().item(), "sigma_mean": sigma.mean().item(),
            "bimodal_fraction": (2 * sigma**2 > 1).float().mean().item()}


_ENVS: dict[tuple[str, bool], list[gym.Env]] = {}


def cached_envs(env_id: str, count: int, render: bool = False) -> list[gym.Env]:
    """count envs of env_id, made once per process (each reset with its seed: as new)."""
    envs = _ENVS.setdefault((env_id, render), [])
    while len(envs) < count:
        envs.append(gym.make(env_id, **({"render_mode": "rgb_array"} if render else {})))
    return envs[:count]


@torch.no_grad()
def run_round(round_: Round) -> dict:
    """The round's episodes, in lockstep: per prefix each episode's return, length, success
    (None: not reported), "unstable" (a physics blow-up ended it), end and q_best's shares;
    "shift" at the states `shift_of` visited ("shift_states" of them)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the same numbers in-process and in a worker
    try:
        return _run_round(round_)
    finally:
        torch.set_num_threads(threads)


def start_key(env: gym.Env) -> bytes | None:
    """The state after reset if the env's steps draw no randomness (H1HandEnv.start_state),
    else None (the episode is distinct)."""
    start_state = getattr(env.unwrapped, "start_state", None)
    return None if start_state is None else start_state()


def first_with_same_start(envs: list[gym.Env]) -> np.ndarray:
    """For each freshly reset env, the index of the first with its start state (else its own)."""
    firsts: dict[bytes, int] = {}
    same = np.arange(len(envs))
    for k, env in enumerate(envs):
        key = start_key(env)
        if key is not None:
            same[k] = firsts.setdefault(key, k)
    return same


def _run_round(round_: Round) -> dict:
    n, result, starts = len(round_.seeds), {}, None
    options = None if round_.reset_noise is None else {"qpos_noise": round_.reset_noise}
    visited: list[tuple[torch.Tensor, torch.Tensor]] = []
    for p, action in round_.actions.items():  # one action's episodes after another's, same envs
        episodes = cached_envs(round_.env_id, n)
        if p in round_.videos:  # its first episode filmed
            episodes = [cached_envs(round_.env_id, 1, render=True)[0], *episodes[1:]]
        obs = np.stack([env.reset(seed=s, options=options)[0]
                        for env, s in zip(episodes, round_.seeds, strict=True)])
        if starts is None:  # each episode follows the first with its start state
            starts = first_with_same_start(episodes)
            result["distinct_episodes"] = len(set(starts.tolist()))
        same = np.arange(n) if action == "sample" else starts  # its noise differs per episode
        first = same == np.arange(n)
        done, returns, lengths = np.zeros(n, bool), np.zeros(n), np.zeros(n, np.int64)
        # Each episode's success (None: not reported), whether a physics blow-up ended it (h1hand
        # truncates: not an ordinary short episode) and why it ended.
        ended = [(None, False, "")] * n
        chosen = np.zeros(len(Q_BEST_CANDIDATES), np.int64)
        generators = [torch.Generator().manual_seed(s) for s in round_.seeds]
        frames = []
        while not done.all():
            live = ~done
            obs_t = torch.as_tensor(obs, dtype=torch.float32)
            mu, log_std = round_.actor(obs_t)
            y, choice = select_actions(action, mu, log_std, obs_t, round_, generators)
            actions = round_.actor.scale(y).numpy()
            bad = np.flatnonzero(live & ~np.isfinite(actions).all(1))
            if bad.size:
                k = int(bad[0])
                raise EvalError(
                    f"{round_.label}: the evaluation action {action_name(action)!r} is NaN/inf "
                    f"in episode {k} (reset seed {round_.seeds[k]}); the actor diverged: resume "
                    "from an earlier checkpoint or lower the learning rates")
            if choice is not None:
                chosen += np.bincount(choice.numpy()[live], minlength=len(Q_BEST_CANDIDATES))
            if p == round_.shift_of:
                visited.append((mu[live], log_std[live]))
            for k in np.flatnonzero(live & first):
                if k == 0 and p in round_.videos:
                    frames.append(episodes[k].render())
                obs[k], reward, terminated, truncated, info = episodes[k].step(actions[k])
                returns[k] += float(reward)
                lengths[k] += 1
                if terminated or truncated:
                    done[k] = True
                    ended[k] = (info.get("success"), bool(info.get("physics_unstable", False)),
                                episode_end(terminated, info))
            # A follower is its first episode again: same rows, same numbers, ending together.
            for k in np.flatnonzero(live & ~first):
                j = same[k]
                obs[k], returns[k], lengths[k], done[k] = obs[j], returns[j], lengths[j], done[j]
                ended[k] = ended[j]
        if p in round_.videos:
            import imageio  # only for videos

            round_.videos[p].parent.mkdir(parents=True, exist_ok=True)
            imageio.mimsave(round_.videos[p], frames,
                            fps=episodes[0].metadata.get("render_fps", 30))
        successes, unstable, ends = (list(column) for column in zip(*ended, strict=True))
        result[p] = {"returns": returns.tolist(), "lengths": lengths.tolist(),
                     "successes": successes, "unstable": unstable, "ends": ends}
        if action == "q_best":
            shares = chosen / max(chosen.sum(), 1)
            result[p]["shares"] = dict(zip(Q_BEST_CANDIDATES, shares.tolist(), strict=True))
    if round_.shift_of is not None:
        mu, log_std = (torch.cat(t) for t in zip(*visited, strict=True))
        result["shift"] = shift_statistics(mu, log_std, round_.mode_solver)
        result["shift_states"] = len(mu)  # to pool the statistics of several rounds
    return result


def episode_end(terminated: bool, info: dict) -> str:
    """Why an episode ended: the task's reason (h1hand: "fell", "dropped", "success"; else
    "terminated"), "blow_up" (physics) or "time_limit"."""
    if terminated:
        return info.get("termination", "terminated")
    return "blow_up" if info.get("physics_unstable", False) else "time_limit"


def round_statistics(result: dict, prefix: str) -> dict:
    """eval.csv's statistics of one prefix, with q_best's shares as q_best_share_<candidate>."""
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
    """eval.csv's statistics of a round (eval_columns): distinct episodes, each prefix's, shift."""
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


def _init_worker() -> None:
    """One thread; stopping is the training process's, and the worker dies with it."""
    torch.set_num_threads(1)
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1, signal.SIGUSR2):
        signal.signal(s, signal.SIG_IGN)
    try:  # Linux: the kernel kills this worker when its parent dies, SIGKILL included
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class EvalPool:
    """Rounds run by `workers` processes (0: at once, in-process); `on_done(round, result)` in
    submission order. Past two in flight per worker, submit first waits for the oldest.
    A failed round ends the run with one line naming it and the cause (SystemExit)."""

    def __init__(self, workers: int, on_done: Callable[[Round, dict], None]):
        self.on_done, self.max_pending = on_done, 2 * max(workers, 1)
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
        """Stops at once, the workers killed: returns the rounds not handed back, in order (a
        stop's checkpoint keeps them for the resumed run to rerun: a round is a pure function)."""
        rounds = [round_ for _, round_ in self.pending]
        self.pending.clear()
        if self.executor is not None:
            # Workers ignore SIGTERM, and exit would still wait for their running rounds.
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
