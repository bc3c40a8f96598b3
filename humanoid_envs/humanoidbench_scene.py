"""Our tasks on HumanoidBench's own compiled scene: its XML and collision meshes, read from a
HumanoidBench checkout, under whatever MuJoCo is installed (HumanoidBench pins 3.1.6).

Why: the one difference left between our physics and HumanoidBench's is the collision shapes
(its meshes, our primitives) and the MuJoCo version. Training in this env asks whether either
is why our cube runs learn less than HumanoidBench's SAC (results/cube-hb-scene/). Only the
compiled model changes: our task code (reset, observation, reward, termination) and H1HandEnv's
stepping run on it, which works because HumanoidBench's model has our joint, actuator, site and
body names in our order. Nothing of HumanoidBench is copied here; it is loaded from the path.

    HUMANOIDBENCH=/path/to/humanoid-bench python sac_corrected.py \
        --env-id humanoid_envs.humanoidbench_scene:h1hand-cube-hbscene-v0

`MjModel.from_xml_path` is all this needs from MuJoCo, so the scene loads under 3.1.6, which
has no `MjSpec` (our own scenes need it).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco

from humanoid_envs.base import H1HandEnv, Task
from humanoid_envs.robot import ACTUATOR_NAMES
from humanoid_envs.tasks import cube, powerlift

TASKS: dict[str, type[Task]] = {"cube": cube.Cube, "powerlift": powerlift.Powerlift}


def scene_xml(task_name: str, humanoidbench: str | os.PathLike | None = None) -> Path:
    """HumanoidBench's scene of a task: humanoid_bench/assets/envs/h1hand_pos_<task>.xml."""
    root = humanoidbench or os.environ.get("HUMANOIDBENCH")
    if not root:
        raise ValueError("no HumanoidBench checkout: set HUMANOIDBENCH=/path/to/humanoid-bench "
                         "(github.com/carlosferrazza/humanoid-bench, its assets included)")
    xml = Path(root) / "humanoid_bench" / "assets" / "envs" / f"h1hand_pos_{task_name}.xml"
    if not xml.is_file():
        raise ValueError(f"{xml} not found: HUMANOIDBENCH must name a HumanoidBench checkout "
                         "with its assets (humanoid_bench/assets/envs/)")
    return xml


class HumanoidBenchSceneEnv(H1HandEnv):
    """H1HandEnv on HumanoidBench's compiled scene instead of ours."""

    def __init__(self, task: Task, xml: Path, **kwargs: Any) -> None:
        self.xml = xml
        super().__init__(task, **kwargs)

    def _compile_scene(self, task: Task, width: int, height: int) -> mujoco.MjModel:
        model = mujoco.MjModel.from_xml_path(str(self.xml))
        names = [model.actuator(i).name for i in range(model.nu)]
        if names != list(ACTUATOR_NAMES):
            raise ValueError(f"{self.xml}: its actuators are not ours in our order; this env "
                             "needs HumanoidBench's h1hand scenes")
        model.vis.global_.offwidth = max(width, model.vis.global_.offwidth)
        model.vis.global_.offheight = max(height, model.vis.global_.offheight)
        return model


def make_env(task_name: str, humanoidbench: str | None = None, **kwargs: Any) -> H1HandEnv:
    """gymnasium entry point (kwargs: humanoidbench, else $HUMANOIDBENCH; render_mode, ...)."""
    return HumanoidBenchSceneEnv(TASKS[task_name](), scene_xml(task_name, humanoidbench), **kwargs)


for _name, _task in TASKS.items():
    _id = f"h1hand-{_name}-hbscene-v0"
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=make_env, max_episode_steps=_task.episode_steps,
                     kwargs={"task_name": _name})
