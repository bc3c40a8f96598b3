"""Our policies in HumanoidBench's own physics: one snapshot acting in our h1hand scene and in
HumanoidBench's compiled scene of the same task (its collision meshes, its XML), from the same
starts.

Why: our robot collides through primitives where HumanoidBench's has meshes (the fingertips
among them), the one difference left in the physics. If a policy of ours scores the same in
both scenes, the physics it meets is not what separates our curves from HumanoidBench's; a gap
here would say it might be. Our task code (reset, observation, reward, termination) runs on
both models, which share joint, actuator, site and body names and order, so the two scenes
start every episode from the same state (checked below).

Needs a checkout of HumanoidBench (github.com/carlosferrazza/humanoid-bench, meshes included);
run from the repository root:
    python bench/bench_hb_physics.py --humanoidbench PATH SNAPSHOT [SNAPSHOT ...]
Prints a markdown table, one row per snapshot and scene: tanh(mu) from --episodes starts (mean
return and its standard error, the paired difference HumanoidBench - ours and its SE, mean
length, how episodes ended); then the policy's sampled (training-time) actions for
--sampled-steps env steps: episodes, mean return, steps where a hand joint turned faster than
100 and 1000 rad/s, physics blow-ups.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import humanoid_envs  # noqa: E402,F401  (registers the envs)
from analysis.estimators import standard_error  # noqa: E402
from humanoid_envs.base import H1HandEnv  # noqa: E402
from humanoid_envs.robot import NV_ROBOT  # noqa: E402
from sac_utils.eval_rounds import episode_end  # noqa: E402
from sac_utils.policies import load_policy  # noqa: E402

# qvel of the two hands: after the free base's 6 dofs and the 21 of legs, torso and arms.
HAND_DOFS = slice(6 + 21, NV_ROBOT)


def scenes(env_id: str, humanoidbench: Path) -> dict[str, gym.Env]:
    """Our env and the same task on HumanoidBench's compiled scene, both with the time limit."""
    task_name = env_id.split("-")[1]
    xml = humanoidbench / "humanoid_bench" / "assets" / "envs" / f"h1hand_pos_{task_name}.xml"
    if not xml.is_file():
        sys.exit(f"{xml} not found: pass --humanoidbench a HumanoidBench checkout with its assets")

    class HumanoidBenchScene(H1HandEnv):
        @staticmethod
        def _compile_scene(task, width: int, height: int) -> mujoco.MjModel:
            return mujoco.MjModel.from_xml_path(str(xml))

    ours = gym.make(env_id)
    task = gym.make(env_id).unwrapped.task  # a second instance: the scene rebinds it
    theirs = gym.wrappers.TimeLimit(HumanoidBenchScene(task), ours.spec.max_episode_steps)
    for k in range(3):
        a, b = ours.reset(seed=k)[0], theirs.reset(seed=k)[0]
        if a.shape != b.shape or not np.array_equal(a, b):
            sys.exit(f"{env_id}: the two scenes start differently (reset seed {k}); "
                     "the models no longer share their layout")
    return {"ours": ours, "HumanoidBench": theirs}


def act(actor: torch.nn.Module, obs: np.ndarray, generator: torch.Generator | None) -> np.ndarray:
    """tanh(mu), or a sample of the policy where a generator is given."""
    with torch.no_grad():
        mu, log_std = actor(torch.as_tensor(obs[None], dtype=torch.float32))
        if generator is not None:
            mu = mu + torch.randn(mu.shape, generator=generator) * log_std.exp()
    return torch.tanh(mu)[0].numpy().astype(np.float64)


def deterministic(actor: torch.nn.Module, env: gym.Env, episodes: int) -> dict:
    returns, lengths, ends = np.zeros(episodes), np.zeros(episodes), Counter()
    for k in range(episodes):
        obs, _ = env.reset(seed=k)
        while True:
            obs, reward, terminated, truncated, info = env.step(act(actor, obs, None))
            returns[k] += reward
            lengths[k] += 1
            if terminated or truncated:
                ends[episode_end(terminated, info)] += 1
                break
    return {"returns": returns, "length": lengths.mean(), "ends": ends}


def sampled(actor: torch.nn.Module, env: gym.Env, steps: int) -> dict:
    generator, episodes, returns, ret = torch.Generator().manual_seed(0), 0, [], 0.0
    fast = Counter()
    obs, _ = env.reset(seed=0)
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(act(actor, obs, generator))
        ret += reward
        speed = np.abs(env.unwrapped.data.qvel[HAND_DOFS]).max()
        fast[100] += speed > 100
        fast[1000] += speed > 1000
        fast["blow-up"] += bool(info.get("physics_unstable"))
        if terminated or truncated:
            episodes += 1
            returns.append(ret)
            ret = 0.0
            obs, _ = env.reset(seed=episodes)
    return {"episodes": episodes, "return": float(np.mean(returns)), "fast": fast}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("snapshots", type=Path, nargs="+", help="snapshot or final_model.pt files")
    parser.add_argument("--humanoidbench", type=Path, required=True, help="HumanoidBench checkout")
    parser.add_argument("--episodes", type=int, default=20, help="tanh(mu) episodes per scene")
    parser.add_argument("--sampled-steps", type=int, default=40000,
                        help="env steps of sampled actions per scene (0: none)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("| policy | scene | tanh(mu) return +- SE | HumanoidBench - ours +- SE | length | ends "
          "| sampled: episodes, mean return | hand joint > 100 / > 1000 rad/s, blow-ups |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.snapshots:
        actor, _, env_id, _ = load_policy(path, None, need_critic=False)
        rows = {}
        for name, env in scenes(env_id, args.humanoidbench).items():
            rows[name] = deterministic(actor, env, args.episodes)
            if args.sampled_steps:
                rows[name] |= sampled(actor, env, args.sampled_steps)
        label = (f"{path.parent.parent.name} {path.stem}" if path.parent.name == "snapshots"
                 else str(path))
        gap = rows["HumanoidBench"]["returns"] - rows["ours"]["returns"]
        for name, row in rows.items():
            r = row["returns"]
            paired = (f"{gap.mean():+.2f} +- {standard_error(gap):.2f}"
                      if name == "HumanoidBench" else "")
            ends = ", ".join(f"{e} {c}" for e, c in sorted(row["ends"].items()))
            extra = ("| | |" if not args.sampled_steps else
                     f"| {row['episodes']}, {row['return']:.2f} | {row['fast'][100]} / "
                     f"{row['fast'][1000]}, {row['fast']['blow-up']} |")
            print(f"| {label} | {name} | {r.mean():.2f} +- {standard_error(r):.2f} | "
                  f"{paired} | {row['length']:.1f} | {ends} {extra}", flush=True)


if __name__ == "__main__":
    main()
