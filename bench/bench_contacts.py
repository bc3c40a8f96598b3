"""How closely our primitive collision shapes reproduce HumanoidBench's meshes: contacts at the
same poses, and fall times on the same action sequences.

Run from the repository root with a checkout of HumanoidBench (github.com/carlosferrazza/
humanoid-bench, meshes included):
    python bench/bench_contacts.py --humanoidbench PATH [--model-xml OUR.xml] [--poses 1500]
Poses: HumanoidBench's own stand scene driven from its keyframe by random controls (uniform in
the ctrlrange for 50 env steps, then N(0, 0.3) actions for 50, alternating; back to the
keyframe when the pelvis drops below 0.2 m or every 250 steps). At each pose both models get
the same robot qpos; a contact is a pair of bodies touching (robot-robot, or floor-robot). It
prints, for robot-robot pairs without hand bodies and for the floor, how many (pose, pair)
contacts both models have, only ours, only HumanoidBench's. Fall times: env step at which the
pelvis drops below 0.6 m from the keyframe, on 20 fixed action sequences.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from humanoid_envs.robot import ASSET_PATH, KEYFRAME_QPOS, N_SUBSTEPS, NQ_ROBOT  # noqa: E402

HUMANOIDBENCH_SCENE = "humanoid_bench/assets/envs/h1hand_pos_stand.xml"


def contact_pairs(model: mujoco.MjModel, data: mujoco.MjData) -> set[tuple[str, str]]:
    """Robot-robot body pairs in contact (hand bodies aside), and ("floor", body) pairs."""
    pelvis = model.body("pelvis").id
    pairs = set()
    for contact in data.contact:
        b1, b2 = int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])
        names = sorted((model.body(b1).name, model.body(b2).name))
        in_robot = (model.body_rootid[b1] == pelvis, model.body_rootid[b2] == pelvis)
        if all(in_robot) and b1 != b2 and not any(n.startswith(("lh_", "rh_")) for n in names):
            pairs.add(tuple(names))
        elif any(in_robot) and 0 in (b1, b2):
            pairs.add(("floor", model.body(b1 + b2).name))
    return pairs


def humanoidbench_poses(model: mujoco.MjModel, count: int, seed: int) -> list[np.ndarray]:
    """Robot qpos along random-control rollouts of HumanoidBench's own model."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    low, high = model.actuator_ctrlrange.T
    mujoco.mj_resetDataKeyframe(model, data, 0)
    poses = []
    for step in range(count):
        if (step // 50) % 2 == 0:
            action = rng.uniform(-1, 1, model.nu)
        else:
            action = np.clip(rng.normal(0, 0.3, model.nu), -1, 1)
        data.ctrl[:] = low + (action + 1) / 2 * (high - low)
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
        poses.append(data.qpos[:NQ_ROBOT].copy())
        if data.qpos[2] < 0.2 or step % 250 == 249:
            mujoco.mj_resetDataKeyframe(model, data, 0)
    return poses


def pose_contacts(model: mujoco.MjModel, poses: list[np.ndarray]) -> list[set]:
    data = mujoco.MjData(model)
    out = []
    for qpos in poses:
        data.qpos[:NQ_ROBOT] = qpos
        mujoco.mj_forward(model, data)
        out.append(contact_pairs(model, data))
    return out


def fall_step(model: mujoco.MjModel, actions: np.ndarray) -> int:
    """Env step at which the pelvis drops below 0.6 m, starting at the keyframe pose."""
    data = mujoco.MjData(model)
    data.qpos[:NQ_ROBOT] = KEYFRAME_QPOS
    mujoco.mj_forward(model, data)
    low, high = model.actuator_ctrlrange.T
    for step, action in enumerate(actions):
        data.ctrl[:] = low + (action + 1) / 2 * (high - low)
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
        if data.qpos[2] < 0.6:
            return step + 1
    return len(actions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--humanoidbench", type=Path, required=True, help="HumanoidBench checkout")
    parser.add_argument("--model-xml", type=Path, default=ASSET_PATH, help="our robot model")
    parser.add_argument("--poses", type=int, default=1500)
    args = parser.parse_args()
    scene = args.humanoidbench / HUMANOIDBENCH_SCENE
    for flag, path in (("--humanoidbench", scene), ("--model-xml", args.model_xml)):
        if not path.is_file():
            print(f"error: {flag}: {path} not found; pass a HumanoidBench checkout with its "
                  "meshes and an existing model XML", file=sys.stderr)
            sys.exit(2)
    if args.poses < 1:
        print(f"error: --poses must be a positive integer, got {args.poses}", file=sys.stderr)
        sys.exit(2)
    theirs = mujoco.MjModel.from_xml_path(str(scene))
    ours = mujoco.MjModel.from_xml_path(str(args.model_xml))
    poses = humanoidbench_poses(theirs, args.poses, seed=1)
    counts = {"self": [0, 0, 0], "floor": [0, 0, 0]}
    for a, b in zip(pose_contacts(ours, poses), pose_contacts(theirs, poses), strict=True):
        for pairs, column in ((a & b, 0), (a - b, 1), (b - a, 2)):
            for pair in pairs:
                counts["floor" if pair[0] == "floor" else "self"][column] += 1
    print(f"{args.model_xml} vs HumanoidBench at {args.poses} of its poses (pose, pair) contacts:")
    for kind, (both, ours_only, theirs_only) in counts.items():
        print(f"  {kind:5s} both {both:5d}  only ours {ours_only:5d}  only HumanoidBench "
              f"{theirs_only:5d}")
    rng = np.random.default_rng(0)
    sequences = [rng.uniform(-1, 1, (300, 61)) for _ in range(6)]
    sequences += [np.clip(rng.normal(0, 0.3, (300, 61)), -1, 1) for _ in range(6)]
    rng = np.random.default_rng(5)
    sequences += [rng.uniform(-1, 1, (300, 61)) for _ in range(8)]
    ours_falls = np.array([fall_step(ours, s) for s in sequences])
    theirs_falls = np.array([fall_step(theirs, s) for s in sequences])
    print(f"fall step, ours:              {ours_falls.tolist()}")
    print(f"fall step, HumanoidBench:     {theirs_falls.tolist()}")
    print(f"mean |difference|: {np.abs(ours_falls - theirs_falls).mean():.1f} env steps")


if __name__ == "__main__":
    main()
