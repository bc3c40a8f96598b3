"""Env steps per second of the h1hand tasks, and of the bare physics underneath them.

Run from the repository root: `python bench/bench_envs.py [--steps 2000 --repeats 5]`.
For each task it steps `gym.make(id)` (with gymnasium's wrappers, as training uses it) with
uniform random actions on one thread, resetting when an episode ends; then it replays exactly
the same trajectory on the same model with nothing but `mj_step` (10 substeps per env step,
the same controls, the same reset states). The difference is the cost of our Python: action
checks, reward, termination, observation, resets, wrappers. Times are this process's CPU time
(one thread), so other jobs on a shared machine do not count; prints medians over repeats.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import humanoid_envs  # noqa: E402
from humanoid_envs.robot import N_SUBSTEPS  # noqa: E402

# Targets from the issue: 3x HumanoidBench's own env measured on these machines.
TARGETS = {
    "h1hand-powerlift-v0": 1400,
    "h1hand-cube-v0": 1300,
    "h1hand-bookshelf_simple-v0": 850,
    "h1hand-bookshelf_hard-v0": 850,
}


def time_env(env: gym.Env, actions: np.ndarray, seed: int) -> tuple[float, list, np.ndarray]:
    """Seconds to step `env` through `actions` (resets included); the episode starts (step
    index, qpos, qvel) and the final qpos, for the replay."""
    base = env.unwrapped
    env.reset(seed=seed)
    starts = [(0, base.data.qpos.copy(), base.data.qvel.copy())]
    start = time.process_time()
    for i, action in enumerate(actions):
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
            starts.append((i + 1, base.data.qpos.copy(), base.data.qvel.copy()))
    seconds = time.process_time() - start
    return seconds, starts, base.data.qpos.copy()


def time_bare_physics(
    model: mujoco.MjModel, ctrls: np.ndarray, starts: list
) -> tuple[float, np.ndarray]:
    """Seconds for mj_step alone along the same trajectory, and the final qpos."""
    data = mujoco.MjData(model)
    resets = {step: (qpos, qvel) for step, qpos, qvel in starts}

    def reset(step: int) -> None:
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = resets[step]
        mujoco.mj_forward(model, data)

    start = time.process_time()
    for i, ctrl in enumerate(ctrls):
        if i in resets:
            reset(i)
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
    if len(ctrls) in resets:  # the last step ended an episode
        reset(len(ctrls))
    seconds = time.process_time() - start
    return seconds, data.qpos.copy()


def bench(env_id: str, steps: int, repeats: int) -> dict[str, float]:
    env = gym.make(env_id)
    base = env.unwrapped
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, 61)).astype(np.float32)
    ctrls = np.array([base.robot.action_to_ctrl(a.astype(np.float64)) for a in actions])
    env_sps, bare_sps, episodes, same = [], [], 0, True
    time_env(env, actions[:100], seed=0)  # warm-up
    for repeat in range(repeats):
        env_seconds, starts, env_final = time_env(env, actions, seed=repeat)
        bare_seconds, bare_final = time_bare_physics(base.model, ctrls, starts)
        env_sps.append(steps / env_seconds)
        bare_sps.append(steps / bare_seconds)
        episodes += len(starts)
        same &= bool(np.array_equal(env_final, bare_final))
    env.close()
    env_median, bare_median = statistics.median(env_sps), statistics.median(bare_sps)
    return {
        "env": env_median,
        "bare": bare_median,
        "overhead": 100.0 * (bare_median / env_median - 1.0),
        "episode_steps": steps * repeats / episodes,
        "same_trajectory": same,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-ids", nargs="+", default=[*humanoid_envs.ENVS])
    parser.add_argument("--steps", type=int, default=2000, help="env steps per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"{args.steps} env steps x {args.repeats} repeats, uniform random actions, medians")
    header = f"{'task':28s} {'env steps/s':>11s} {'bare mj_step':>12s} {'overhead':>8s}"
    print(f"{header} {'target':>6s} {'mean episode':>12s}  replay matches")
    for env_id in args.env_ids:
        r = bench(env_id, args.steps, args.repeats)
        target = str(TARGETS.get(env_id, "-"))
        print(
            f"{env_id:28s} {r['env']:11.0f} {r['bare']:12.0f} {r['overhead']:7.1f}% "
            f"{target:>6s} {r['episode_steps']:12.1f}  {r['same_trajectory']}"
        )


if __name__ == "__main__":
    main()
