"""What fidelity to HumanoidBench costs: bare physics with and without its contact choices.

Run from the repository root: `python bench/bench_robot.py [--steps 1500 --repeats 5]`.
For each task scene it builds the same model three ways from `robot_spec()`:
- this model: `robot_spec()` as it is, which is HumanoidBench's: robot self-collisions on and
  friction loss 0.01 on the 48 hand joints (collision shapes stay our primitives);
- no self-collisions: hand friction loss still on;
- both off: what this model did before it followed HumanoidBench here.
Each env step is 10 x mj_step with uniform random controls in the actuators' ctrlrange; the
scene goes back to its keyframe when the pelvis drops below 0.2 m or after 1000 env steps.
Times are the thread's CPU time (robust to other processes on the machine); medians over
repeats, variants alternating.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from humanoid_envs.robot import KEYFRAME_QPOS, N_SUBSTEPS, robot_spec  # noqa: E402
from humanoid_envs.tasks.bookshelf import Bookshelf  # noqa: E402
from humanoid_envs.tasks.cube import Cube  # noqa: E402
from humanoid_envs.tasks.powerlift import Powerlift  # noqa: E402
from humanoid_envs.tasks.stand import Stand  # noqa: E402

SCENES = {
    "stand": Stand,
    "powerlift": Powerlift,
    "cube": Cube,
    "bookshelf": lambda: Bookshelf(randomize_order=False),
}
VARIANTS = {
    "this model (HumanoidBench's)": dict(self_collisions=True, hand_frictionloss=0.01),
    "no self-collisions": dict(self_collisions=False, hand_frictionloss=0.01),
    "both off": dict(self_collisions=False, hand_frictionloss=0.0),
}


def build_scene(task, self_collisions: bool, hand_frictionloss: float) -> mujoco.MjModel:
    """The task's scene on a robot with the given self-collision and friction-loss choices."""
    spec = robot_spec()
    # The robot's colliding geoms: every body but the world (whose geom is the floor).
    robot_geoms = [g for body in spec.bodies[1:] for g in body.geoms if g.contype == 1]
    task.add_objects(spec)
    if not self_collisions:  # robot geoms still touch the floor and objects (their conaffinity)
        for geom in robot_geoms:
            geom.conaffinity = 0
    for joint in spec.joints:
        if joint.name.startswith(("lh_", "rh_")):
            joint.frictionloss = hand_frictionloss
    spec.add_key(name="home", qpos=[*KEYFRAME_QPOS, *task.object_qpos])
    return spec.compile()


def env_steps_per_second(model: mujoco.MjModel, steps: int, seed: int) -> tuple[float, float]:
    """Bare-physics env steps per CPU second and the mean number of constraint rows."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    low, high = model.actuator_ctrlrange.T
    mujoco.mj_resetDataKeyframe(model, data, 0)
    seconds, rows = 0.0, 0
    for step in range(steps):
        data.ctrl[:] = rng.uniform(low, high)
        start = time.thread_time()
        mujoco.mj_step(model, data, nstep=N_SUBSTEPS)
        seconds += time.thread_time() - start
        rows += data.nefc
        if data.qpos[2] < 0.2 or step % 1000 == 999:
            mujoco.mj_resetDataKeyframe(model, data, 0)
    return steps / seconds, rows / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=1500, help="env steps per timing")
    parser.add_argument("--repeats", type=int, default=5, help="timings per variant")
    args = parser.parse_args()
    print(f"{args.steps} env steps x {args.repeats} repeats, thread CPU time, medians")
    print(f"{'scene':10s} " + " ".join(f"{v:>26s}" for v in VARIANTS))
    for scene, make_task in SCENES.items():
        models = {v: build_scene(make_task(), **kw) for v, kw in VARIANTS.items()}
        results = {v: [] for v in VARIANTS}
        for repeat in range(args.repeats):
            for variant, model in models.items():
                results[variant].append(env_steps_per_second(model, args.steps, seed=repeat))
        cells = []
        for runs in results.values():
            sps = statistics.median(r[0] for r in runs)
            cells.append(f"{sps:7.0f} steps/s (nefc {statistics.mean(r[1] for r in runs):3.0f})")
        print(f"{scene:10s} " + " ".join(f"{c:>26s}" for c in cells), flush=True)


if __name__ == "__main__":
    main()
