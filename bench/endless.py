"""Envs whose episodes always run to their time limit: the worst case of an evaluation round.

`--env-id bench.endless:Endless-Hopper-v5` (from the repository root) is Hopper-v5 with its
termination ignored; the same for every id in ENDLESS. For benchmarks only.
"""

import gymnasium as gym

import humanoid_envs  # noqa: F401  (registers the h1hand tasks wrapped below)

ENDLESS = ("Hopper-v5", "HalfCheetah-v5", "Ant-v5", "Humanoid-v5", "h1hand-powerlift-v0",
           "h1hand-bookshelf_simple-v0", "h1hand-cube-v0", "h1hand-bookshelf_hard-v0")


class IgnoreTermination(gym.Wrapper):
    def step(self, action):
        obs, reward, _, truncated, info = self.env.step(action)
        return obs, reward, False, truncated, info


def make_endless(base: str, **kwargs) -> gym.Env:
    return IgnoreTermination(gym.make(base, **kwargs))


for _base in ENDLESS:
    if f"Endless-{_base}" not in gym.registry:
        gym.register(f"Endless-{_base}", entry_point=make_endless, kwargs={"base": _base})
