"""powerlift: lift a 104 kg dumbbell from the floor above the head."""

from __future__ import annotations

from typing import Any

import mujoco

from humanoid_envs import rewards
from humanoid_envs.base import (
    HUMANOIDBENCH_QPOS_NOISE,
    H1HandEnv,
    Task,
    add_free_object,
    add_look_at_camera,
    add_solid,
)

# The dumbbell is lifted when its centre is in this height band (m).
_LIFTED_HEIGHT = (1.9, 2.1)
# Below this pelvis height the robot has fallen: the episode ends.
_FALLEN_PELVIS_HEIGHT = 0.2

# The dumbbell's centre starts at (0.5, 0, 0.2), so the plates (radius 0.2) rest on the floor.
_DUMBBELL_QPOS = (0.5, 0.0, 0.2, 1.0, 0.0, 0.0, 0.0)
# Bar and plates are cylinders along y (their z axis turned by -90 degrees about x).
_ALONG_Y = (0.70711, -0.70711, 0.0, 0.0)


class Powerlift(Task):
    """reward = 0.2 * small_control * stand(1.65/3, 0.8) + 0.8 * lifted, where lifted is a
    gaussian tolerance of the dumbbell's height around the band, 0.1 at 2 m from it."""

    episode_steps = 1000
    success_bar = 800.0
    camera = "powerlift_view"
    qpos_noise = HUMANOIDBENCH_QPOS_NOISE
    object_qpos = _DUMBBELL_QPOS

    def add_objects(self, spec: mujoco.MjSpec) -> None:
        dumbbell = add_free_object(
            spec,
            "dumbbell",
            pos=_DUMBBELL_QPOS[:3],
            quat=_DUMBBELL_QPOS[3:],
            mass=103.96567,
            inertia=(59.3788331, 59.3788331, 2.0120636),
            iquat=(0.70711, 0.70711, 0.0, 0.0),
        )
        cylinder, dark = mujoco.mjtGeom.mjGEOM_CYLINDER, (0.25, 0.25, 0.28, 1.0)
        add_solid(dumbbell, cylinder, (0.029, 0.65), quat=_ALONG_Y)
        for side in (1.0, -1.0):
            add_solid(dumbbell, cylinder, (0.2, 0.2), pos=(0, 0.75 * side, 0), quat=_ALONG_Y,
                      rgba=dark)  # fmt: skip
        add_look_at_camera(spec, self.camera, pos=(3.0, -2.2, 1.8), target=(0.3, 0.0, 0.9))

    def bind(self, model, data, robot) -> None:
        super().bind(model, data, robot)
        self._dumbbell = model.body("dumbbell").id

    def dumbbell_height(self) -> float:
        return float(self.data.xpos[self._dumbbell, 2])

    def get_reward(self) -> tuple[float, dict[str, Any]]:
        robot = self.robot
        stand = rewards.stand(
            robot.head_height(), robot.torso_upright(), rewards.STAND_HEIGHT / 3, 0.8
        )
        small_control = rewards.small_control(robot.actuator_forces())
        lifted = rewards.tolerance(self.dumbbell_height(), _LIFTED_HEIGHT, margin=2.0)
        reward = 0.2 * small_control * stand + 0.8 * lifted
        return reward, {"stand": stand, "small_control": small_control, "lifted": lifted}

    def termination(self) -> str:
        return "fell" if self.robot.pelvis_height() < _FALLEN_PELVIS_HEIGHT else ""


def make_env(**kwargs: Any) -> H1HandEnv:
    """gymnasium entry point of `h1hand-powerlift-v0` (kwargs: render_mode, width, height)."""
    return H1HandEnv(Powerlift(), **kwargs)
