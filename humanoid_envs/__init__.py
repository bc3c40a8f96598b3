"""The h1hand humanoid (Unitree H1 body, two Shadow-style hands, 61 actuators) and the
HumanoidBench tasks the paper uses, as gymnasium environments.

Importing the package registers them, so both `import humanoid_envs;
gym.make("h1hand-cube-v0")` and `gym.make("humanoid_envs:h1hand-cube-v0")` work.
"""

import gymnasium as gym

from humanoid_envs.tasks import bookshelf, cube, powerlift, stand

# id -> (entry point, episode length in env steps)
ENVS = {
    "h1hand-stand-v0": ("humanoid_envs.tasks.stand:make_env", stand.Stand.episode_steps),
    "h1hand-powerlift-v0": (
        "humanoid_envs.tasks.powerlift:make_env",
        powerlift.Powerlift.episode_steps,
    ),
    "h1hand-cube-v0": ("humanoid_envs.tasks.cube:make_env", cube.Cube.episode_steps),
    "h1hand-bookshelf_simple-v0": (
        "humanoid_envs.tasks.bookshelf:make_simple_env",
        bookshelf.Bookshelf.episode_steps,
    ),
    "h1hand-bookshelf_hard-v0": (
        "humanoid_envs.tasks.bookshelf:make_hard_env",
        bookshelf.Bookshelf.episode_steps,
    ),
}

for _env_id, (_entry_point, _episode_steps) in ENVS.items():
    if _env_id not in gym.registry:
        gym.register(id=_env_id, entry_point=_entry_point, max_episode_steps=_episode_steps)

# HumanoidBench's own scenes of cube and powerlift (h1hand-<task>-hbscene-v0), loaded from the
# checkout $HUMANOIDBENCH names when made.
from humanoid_envs import humanoidbench_scene  # noqa: E402,F401
