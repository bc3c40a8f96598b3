"""stand: keep standing still (not in the paper; a small task for quick learning checks)."""

from __future__ import annotations

from typing import Any

from humanoid_envs import rewards
from humanoid_envs.base import HUMANOIDBENCH_QPOS_NOISE, H1HandEnv, Task, add_look_at_camera

# Below this pelvis height the robot has fallen: the episode ends.
_FALLEN_PELVIS_HEIGHT = 0.2


class Stand(Task):
    """Reset as powerlift (keyframe plus qpos noise); reward =
    small_control * stand(1.65/4, 0.9) * dont_move."""

    episode_steps = 1000
    success_bar = 800.0
    camera = "stand_view"
    qpos_noise = HUMANOIDBENCH_QPOS_NOISE

    def add_objects(self, spec) -> None:
        add_look_at_camera(spec, self.camera, pos=(2.5, -2.5, 1.6), target=(0.0, 0.0, 1.0))

    def get_reward(self) -> tuple[float, dict[str, Any]]:
        robot = self.robot
        stand = rewards.stand(
            robot.head_height(), robot.torso_upright(), rewards.STAND_HEIGHT / 4, 0.9
        )
        small_control = rewards.small_control(robot.actuator_forces())
        dont_move = rewards.dont_move(*robot.center_of_mass_velocity()[:2])
        reward = small_control * stand * dont_move
        return reward, {"stand": stand, "small_control": small_control, "dont_move": dont_move}

    def termination(self) -> str:
        return "fell" if self.robot.pelvis_height() < _FALLEN_PELVIS_HEIGHT else ""


def make_env(**kwargs: Any) -> H1HandEnv:
    """gymnasium entry point of `h1hand-stand-v0` (kwargs: render_mode, width, height)."""
    return H1HandEnv(Stand(), **kwargs)
