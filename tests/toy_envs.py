"""Tiny gymnasium envs whose episodes are known from their reset seed, for eval_rounds' tests.

gym.make("tests.toy_envs:Countdown-v0") imports this module, in a worker process too.
"""

import math
import os
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn


def episode_of(seed: int) -> tuple[int, float, bool]:
    """The length, per-step reward and success of the episode that reset seed starts."""
    return 1 + seed % 13, 0.5 + seed % 5, seed % 2 == 0


# Evaluation episodes reset with 32-bit seeds from eval_seeds; a training run's first reset uses
# its small --seed and later ones none: seeds above this mark an evaluation episode.
EVAL_SEEDS_ABOVE = 2**20


class Countdown(gym.Env):
    """Ends after a length fixed by the reset seed; every step pays the same reward. The
    observation is (steps left, the seed's reward, 1); actions are ignored. `step_seconds` slows
    each step down, so that a long round takes visibly longer than a short one; `eval_only`
    applies it (and `nan_obs`, NaN observations) to evaluation episodes only. With `gated`, an
    episode's second step waits until the file named by $TOY_ENVS_GATE exists: a test holds a
    long episode back for as long as it needs, whatever the machine's load."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, step_seconds: float = 0.0, nan_obs: bool = False, eval_only: bool = False,
                 gated: bool = False):
        self.step_seconds, self.nan_obs, self.eval_only = step_seconds, nan_obs, eval_only
        self.gated, self.steps = gated, 0
        self.left, self.reward, self.success, self.evaluating = 0, 0.0, False, False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.evaluating = seed is not None and seed > EVAL_SEEDS_ABOVE
        length, self.reward, self.success = episode_of(seed if seed is not None else 0)
        self.left, self.steps = length, 0
        return self._obs(), {}

    def step(self, action):
        assert self.left > 0, "stepped after the episode ended"
        if self.evaluating or not self.eval_only:
            time.sleep(self.step_seconds)
        if self.gated and self.steps == 1 and (self.evaluating or not self.eval_only):
            wait_for_gate()
        self.left -= 1
        self.steps += 1
        done = self.left == 0
        return self._obs(), self.reward, done, False, {"success": self.success} if done else {}

    def _obs(self) -> np.ndarray:
        nan = self.nan_obs and (self.evaluating or not self.eval_only)
        return np.array([self.left, self.reward, math.nan if nan else 1.0])


def wait_for_gate(timeout: float = 120.0) -> None:
    gate, deadline = Path(os.environ["TOY_ENVS_GATE"]), time.monotonic() + timeout
    while not gate.exists():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{gate} never appeared")
        time.sleep(0.01)


gym.register("Countdown-v0", entry_point=Countdown)
gym.register("GatedCountdown-v0", entry_point=Countdown, kwargs={"gated": True})
gym.register("SlowEval-v0", entry_point=Countdown, kwargs={"step_seconds": 0.02, "eval_only": True})
gym.register("NanEval-v0", entry_point=Countdown, kwargs={"nan_obs": True, "eval_only": True})
gym.register("GatedEval-v0", entry_point=Countdown, kwargs={"gated": True, "eval_only": True})


class ToyActor(nn.Module):
    """mu from the observation, sigma 1, actions unscaled; mu is NaN where the observation's
    reward entry equals `nan_reward` (one chosen episode)."""

    def __init__(self, nan_reward: float | None = None):
        super().__init__()
        self.nan_reward = nan_reward

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mu = torch.stack([0.1 * obs[:, 1], -0.2 * obs[:, 2]], 1)
        if self.nan_reward is not None:
            mu = torch.where((obs[:, 1] == self.nan_reward)[:, None], math.nan, mu)
        return mu, torch.zeros_like(mu)

    def scale(self, y: torch.Tensor) -> torch.Tensor:
        return y


class ToyCritic(nn.Module):
    """Q1 = -|a - target|^2, Q2 = Q1 + 1: the best action is the one nearest the target."""

    def __init__(self, target: torch.Tensor):
        super().__init__()
        self.target = target

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        q1 = -(action - self.target).pow(2).sum(1)
        return torch.stack([q1, q1 + 1])


class FailingEval(Countdown):
    """A Countdown whose evaluation episodes raise the env's own error at their first step."""

    def step(self, action):
        if self.evaluating:
            raise ValueError("the toy env's own failure")
        return super().step(action)


gym.register("FailingEval-v0", entry_point=FailingEval)


class BlowUp(Countdown):
    """Episodes of 4 steps whose 4th is a physics blow-up, reported as H1HandEnv does: the
    previous observation, reward 0, truncated, info["physics_unstable"]."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.left, self.reward = 4, 1.0
        return self._obs(), {}

    def step(self, action):
        if self.left == 1:
            return self._obs(), 0.0, False, True, {"physics_unstable": True}
        return super().step(action)


gym.register("BlowUp-v0", entry_point=BlowUp, max_episode_steps=50)


class OddBlowUp(Countdown):
    """A Countdown (its episode from episode_of) whose episodes from odd reset seeds end in a
    physics blow-up, reported as BlowUp's, at their last step instead of ending normally. Its
    start state is its reset seed (its steps draw no randomness), as H1HandEnv.start_state tells
    it: an episode whose seed repeats an earlier one's is that episode again."""

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.start = seed
        return super().reset(seed=seed, options=options)

    def step(self, action):
        if self.left == 1 and self.start is not None and self.start % 2:
            self.left = 0
            return self._obs(), 0.0, False, True, {"physics_unstable": True}
        return super().step(action)

    def start_state(self) -> bytes:
        return str(self.start).encode()


gym.register("OddBlowUp-v0", entry_point=OddBlowUp)
