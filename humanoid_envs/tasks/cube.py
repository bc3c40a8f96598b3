"""cube: hold a cube on each palm and turn both to the target cube's orientation."""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from humanoid_envs import rewards
from humanoid_envs.base import H1HandEnv, Task, add_free_object, add_look_at_camera, add_solid

# Episode ends when the pelvis or either cube drops below these heights (m).
_FALLEN_PELVIS_HEIGHT = 0.58
_DROPPED_CUBE_HEIGHT = 0.6
# A hand is close to its cube within this distance (m) of it.
_CLOSE_DISTANCE = 0.1
# Roll, pitch and yaw of the cubes and the target are drawn uniformly from +-this (rad).
_MAX_ANGLE = 3.14

_CUBE_HALF_SIZE = 0.025
_CUBE_MASS = 0.0625
_CUBE_INERTIA = (2.6e-05, 2.6e-05, 2.6e-05)
# The cubes start above the palms and fall onto them; the target floats in front of the head.
_CUBE_START = {
    "left_cube_to_rotate": (0.45, 0.21, 1.125),
    "right_cube_to_rotate": (0.45, -0.21, 1.125),
}
_TARGET_POS = (0.5, 0.0, 1.5)


def _random_orientation(np_random: np.random.Generator) -> np.ndarray:
    """Quaternion of roll-pitch-yaw angles drawn uniformly in [-3.14, 3.14] (extrinsic x, y, z)."""
    quat = np.empty(4)
    mujoco.mju_euler2Quat(quat, np_random.uniform(-_MAX_ANGLE, _MAX_ANGLE, 3), "XYZ")
    return quat


class Cube(Task):
    """reward = 0.2 * small_control * stand(1.65/4, 0.9) * dont_move + 0.5 * orient + 0.3 * close.

    orient: mean over cubes of a gaussian tolerance of |q_cube - q_target| (L2 of the
    quaternions' 4-vectors, as HumanoidBench), 0.1 at 0.3; close: mean over hands of a gaussian
    tolerance of the distance of each hand site to its cube beyond 0.1 m, 0.1 at 0.5 m more.
    """

    episode_steps = 500
    success_bar = 370.0
    camera = "cube_view"
    object_qpos = tuple(x for pos in _CUBE_START.values() for x in (*pos, 1.0, 0.0, 0.0, 0.0))

    def add_objects(self, spec: mujoco.MjSpec) -> None:
        box, half = mujoco.mjtGeom.mjGEOM_BOX, (_CUBE_HALF_SIZE,) * 3
        for (name, pos), rgba in zip(
            _CUBE_START.items(), ((0.9, 0.3, 0.2, 1.0), (0.2, 0.4, 0.9, 1.0)), strict=True
        ):
            cube = add_free_object(spec, name, pos, (1, 0, 0, 0), _CUBE_MASS, _CUBE_INERTIA)
            add_solid(cube, box, half, rgba=rgba)
        # The target only shows the orientation: no joint, no collisions.
        target = spec.worldbody.add_body(name="target_cube", pos=list(_TARGET_POS))
        target.add_geom(type=box, size=list(half), rgba=[0.2, 0.8, 0.3, 0.6], contype=0,
                        conaffinity=0)  # fmt: skip
        add_look_at_camera(spec, self.camera, pos=(1.6, -1.0, 1.7), target=(0.4, 0.0, 1.2))

    def bind(self, model, data, robot) -> None:
        super().bind(model, data, robot)
        self._cubes = tuple(model.body(name).id for name in _CUBE_START)  # left, right
        self._target = model.body("target_cube").id

    def initialize_episode(self, np_random: np.random.Generator) -> None:
        for cube in self._cubes:
            qposadr = self.model.jnt_qposadr[self.model.body_jntadr[cube]]
            self.data.qpos[qposadr + 3 : qposadr + 7] = _random_orientation(np_random)
        self.model.body_quat[self._target] = _random_orientation(np_random)

    def episode_state(self) -> tuple[np.ndarray, ...]:
        return (self.model.body_quat[self._target],)

    def get_observation(self) -> np.ndarray:
        return np.concatenate((self.data.qpos, self.data.qvel, self.model.body_quat[self._target]))

    def get_reward(self) -> tuple[float, dict[str, Any]]:
        robot, xpos, xquat = self.robot, self.data.xpos, self.data.xquat
        stand = rewards.stand(
            robot.head_height(), robot.torso_upright(), rewards.STAND_HEIGHT / 4, 0.9
        )
        small_control = rewards.small_control(robot.actuator_forces())
        dont_move = rewards.dont_move(*robot.center_of_mass_velocity()[:2])
        target = self.model.body_quat[self._target]
        hands = (robot.left_hand_position(), robot.right_hand_position())
        orient = close = 0.0
        for cube, hand in zip(self._cubes, hands, strict=True):
            orient += rewards.tolerance(math.dist(xquat[cube], target), margin=0.3) / 2
            distance = math.dist(hand, xpos[cube])
            close += rewards.tolerance(distance, (0.0, _CLOSE_DISTANCE), margin=0.5) / 2
        reward = 0.2 * small_control * stand * dont_move + 0.5 * orient + 0.3 * close
        return reward, {
            "stand": stand,
            "small_control": small_control,
            "dont_move": dont_move,
            "orient": orient,
            "close": close,
        }

    def termination(self) -> str:
        if self.robot.pelvis_height() < _FALLEN_PELVIS_HEIGHT:
            return "fell"
        xpos = self.data.xpos
        dropped = min(xpos[cube, 2] for cube in self._cubes) < _DROPPED_CUBE_HEIGHT
        return "dropped" if dropped else ""


def make_env(**kwargs: Any) -> H1HandEnv:
    """gymnasium entry point of `h1hand-cube-v0` (kwargs: render_mode, width, height)."""
    return H1HandEnv(Cube(), **kwargs)
