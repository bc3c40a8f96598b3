"""The MuJoCo version screen: our snapshots acting in HumanoidBench's own compiled scene of their
task (h1hand-<task>-hbscene-v0) under the MuJoCo this interpreter has, episodes paired by start
across versions.

Why: HumanoidBench pins mujoco==3.1.6 and we run 4.0.0; the same scene stepped under the two
with the same actions parts by 1e-3 m within a few steps. If a policy scores the same under both,
the version is not what separates our cube curves from HumanoidBench's; a gap says it might be.

Two steps, one per interpreter (the project stays on 4.0.0; 3.1.6 goes in a venv of its own with
this project's requirements but `mujoco==3.1.6`), then the comparison:

    HUMANOIDBENCH=PATH .venv/bin/python bench/bench_mujoco_version.py act --out v400.csv SNAP...
    HUMANOIDBENCH=PATH venv316/bin/python bench/bench_mujoco_version.py act --out v316.csv SNAP...
    .venv/bin/python bench/bench_mujoco_version.py compare v400.csv v316.csv

`act` writes one row per episode (snapshot, action, start, MuJoCo version, return, length, how it
ended); start k is `reset(seed=k)` with the robust evaluation's reset noise (+-0.01 on qpos), a
draw from numpy alone, so both versions start from the same state. `compare` prints a markdown
table per snapshot and action: the mean return under each version and the paired difference
(second file minus first) +- the standard error of its paired episodes, "differs" past 3 of them.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter, defaultdict
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import humanoid_envs  # noqa: E402,F401  (registers the envs, the hbscene ones among them)
from mode_search import mode_action  # noqa: E402
from sac_utils.eval_rounds import episode_end  # noqa: E402
from sac_utils.policies import load_policy  # noqa: E402

FIELDS = ("snapshot", "action", "start", "mujoco", "return", "length", "end")


def label(path: Path) -> str:
    """`<run> step<N>` for a run's snapshot, else the path."""
    if path.parent.name == "snapshots":
        return f"{path.parent.parent.name} {path.stem}"
    return str(path)


def act(path: Path, starts: int, reset_noise: float, actions: list[str]) -> list[dict]:
    trained_on = torch.load(path, map_location="cpu", weights_only=True)["config"]["env_id"]
    # The actor is rebuilt against the hbscene env: ours needs MjSpec, which 3.1.6 lacks.
    env_id = trained_on.replace("-v0", "-hbscene-v0")
    actor, _, _, _ = load_policy(path, env_id, need_critic=False)
    env = gym.make(env_id)
    rows = []
    for name in actions:
        for k in range(starts):
            obs, _ = env.reset(seed=k, options={"qpos_noise": reset_noise})
            ret, length = 0.0, 0
            while True:
                with torch.no_grad():
                    mu, log_std = actor(torch.as_tensor(obs[None], dtype=torch.float32))
                    a = torch.tanh(mu) if name == "tanh_mu" else mode_action(mu, log_std)
                obs, reward, terminated, truncated, info = env.step(a[0].double().numpy())
                ret, length = ret + reward, length + 1
                if terminated or truncated:
                    break
            rows.append({"snapshot": label(path), "action": name, "start": k,
                         "mujoco": mujoco.__version__, "return": ret, "length": length,
                         "end": episode_end(terminated, info)})
    return rows


def ends(rows: dict, keys: list) -> str:
    return ", ".join(f"{e} {c}" for e, c in sorted(Counter(rows[k]["end"] for k in keys).items()))


def compare(first: Path, second: Path) -> None:
    def read(path: Path) -> dict:
        with path.open() as f:
            return {(r["snapshot"], r["action"], int(r["start"])): r for r in csv.DictReader(f)}

    a, b = read(first), read(second)
    if a.keys() != b.keys():
        sys.exit(f"{first} and {second} hold different episodes; run `act` with the same "
                 "snapshots, --starts and --actions in both")
    va, vb = next(iter(a.values()))["mujoco"], next(iter(b.values()))["mujoco"]
    groups = defaultdict(list)
    for key in a:
        groups[key[:2]].append(key)
    print(f"| snapshot | action | starts | return, MuJoCo {va} | return, MuJoCo {vb} | "
          f"{vb} - {va} +- SE | | length {va} / {vb} | ends {va} / {vb} |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (snapshot, action), keys in groups.items():
        ra = np.array([float(a[k]["return"]) for k in keys])
        rb = np.array([float(b[k]["return"]) for k in keys])
        d = rb - ra
        se = d.std(ddof=1) / np.sqrt(len(d))
        verdict = "differs" if abs(d.mean()) > 3 * se else "level"
        la = np.mean([int(a[k]["length"]) for k in keys])
        lb = np.mean([int(b[k]["length"]) for k in keys])
        print(f"| {snapshot} | {action} | {len(keys)} | {ra.mean():.2f} | {rb.mean():.2f} | "
              f"{d.mean():+.2f} +- {se:.2f} ({abs(d.mean()) / se:.1f} SE) | {verdict} | "
              f"{la:.1f} / {lb:.1f} | {ends(a, keys)} / {ends(b, keys)} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("act", help="act with each snapshot under this interpreter's MuJoCo")
    p.add_argument("snapshots", type=Path, nargs="+", help="snapshot or final_model.pt files")
    p.add_argument("--out", type=Path, required=True, help="CSV to write, one row per episode")
    p.add_argument("--starts", type=int, default=100, help="episodes per snapshot and action")
    p.add_argument("--reset-noise", type=float, default=0.01, help="half-width on qpos")
    p.add_argument("--actions", nargs="+", default=["tanh_mu", "mode"],
                   choices=["tanh_mu", "mode"], help="the evaluation actions")
    c = sub.add_parser("compare", help="pair two `act` files by start")
    c.add_argument("first", type=Path)
    c.add_argument("second", type=Path)
    args = parser.parse_args()
    if args.command == "compare":
        return compare(args.first, args.second)
    torch.set_num_threads(1)
    rows = []
    for path in args.snapshots:
        rows += act(path, args.starts, args.reset_noise, args.actions)
        print(f"{label(path)}: {len(rows)} episodes so far", file=sys.stderr, flush=True)
    tmp = args.out.with_suffix(".part")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(args.out)


if __name__ == "__main__":
    main()
